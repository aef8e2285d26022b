"""Quasi-dense matching (Lhuillier & Quan, PAMI 2005): seed propagation + resampling.

1. **Seeds**: verified SIFT matches (ratio test, mutual check, robust F),
   rounded to whole pixels.
2. **Propagation** (best first): a priority queue holds accepted matches keyed by
   their ZNCC. The best match ``(x, x')`` is popped; every left pixel ``u`` in its
   ``(2r+1) x (2r+1)`` neighbourhood is tried against the right pixels
   ``u' = u + (x' - x) + delta`` with ``|delta|_inf <= eps`` (the disparity-gradient
   limit). A candidate needs ZNCC over a small window above ``zncc_min``, texture
   above ``texture_min`` in both images (with the seeds' F: the window's mean
   gradient along the epipolar line, which rejects aperture-ambiguous windows;
   without F: the largest difference to a 4-neighbour, as in the paper) and, when
   F is known, ``u'`` within ``epipolar_band_px`` of the epipolar line of ``u``.
   Candidates are accepted best first when neither ``u`` nor ``u'`` is matched yet
   (uniqueness in both images) and are pushed on the queue in turn.
2b. **Reseeding**: a region without a SIFT seed of its own (a leaf separated from its
   neighbours by background) is never reached by growth alone. With F, textured left
   pixels far from every match are matched by a ZNCC search along their epipolar
   line within the displacements seen so far (a distinct peak, left-right
   consistent) and grow in a further pass; up to ``reseed_rounds`` passes.
3. **Resampling**: the left image is cut into ``cell_px`` x ``cell_px`` regions; a
   local affine map (or homography) is fitted by RANSAC to the propagated matches
   of each region, and a region whose fit explains at least ``min_inlier_share``
   of its matches and whose inliers spread over an area (a thin line of matches
   is accepted only where no match nearby disagrees with the fit: one surface, not
   an occlusion edge) emits one match: its centre (when the inliers surround it)
   or the inliers' centroid, and that point's image under the map. A final robust
   F over the resampled matches removes the inconsistent ones.
   Two checks keep the matches correct (>= 95 % within 1 px of Middlebury's ground
   truth): windows whose only structure is an edge nearly along the epipolar line
   are not propagated into and carry no match (:func:`aperture_coupling`: with rows a
   fraction of a pixel apart an integer match there is pixels off), and a region's
   match is placed on an inlier whose neighbours along the epipolar line are matched
   consistently further than the ZNCC window reaches (``interior_px``): the band a
   window smears a foreground's displacement into past a depth edge emits nothing.

The propagation and the resampling are numba kernels (single thread: the
propagation is inherently sequential); the propagation caches each left pixel's
candidate ZNCCs for the last displacement it was reached with. Pixels: ``u`` right, ``v`` down, top-left
pixel centre at (0, 0).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from canopy_stereo.errors import CanopyStereoError, MatchingError
from canopy_stereo.features.descriptor_matching import match_descriptors
from canopy_stereo.features.detectors import detect_and_describe, make_detector
from canopy_stereo.features.result import DISTRIBUTION_CELL_PX, MatchResult
from canopy_stereo.features.sparse import verify_matches
from canopy_stereo.geometry.fundamental import MIN_MATCHES_F, estimate_fundamental

# ----------------------------------------------------------------------------------------------
# Window statistics for ZNCC


def epipoles(F: np.ndarray):
    """Left and right epipoles (homogeneous, unit norm) of F: ``F e_l = 0``, ``F^T e_r = 0``."""
    _, _, vt = np.linalg.svd(F)
    e_left = vt[-1]
    _, _, vt = np.linalg.svd(F.T)
    e_right = vt[-1]
    return e_left / np.linalg.norm(e_left), e_right / np.linalg.norm(e_right)


def _epipolar_gradients(img: np.ndarray, epipole):
    """Intensity gradient (Sobel, grey levels per pixel) of a float (H, W) image along and
    across the epipolar line through each pixel (direction from the epipole, homogeneous
    3-vector, to the pixel; either sign): ``(g_along, g_across)``, float64 (H, W) each."""
    h, w = img.shape
    gx = cv2.Sobel(img, cv2.CV_64F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_64F, 0, 1, ksize=3) / 8.0
    ex, ey, ew = (float(c) for c in np.asarray(epipole, np.float64).ravel())
    u = np.arange(w, dtype=np.float64)[None, :]
    v = np.arange(h, dtype=np.float64)[:, None]
    dx = ew * u - ex
    dy = ew * v - ey
    norm = np.hypot(dx, dy)
    norm[norm < 1e-12] = 1.0
    dx, dy = dx / norm, dy / norm
    return gx * dx + gy * dy, gy * dx - gx * dy


def texture_map(gray: np.ndarray, half_window: int, *, epipole=None) -> np.ndarray:
    """Texture of each pixel's matching window, grey levels per pixel, float64 (H, W).

    Without an epipole: the largest absolute difference to a 4-neighbour
    (Lhuillier & Quan's measure). With the image's epipole (homogeneous 3-vector,
    from F): the window mean of ``|grad I . e|``, the intensity gradient along the
    epipolar line through the pixel. Windows whose only structure runs along the
    epipolar line (the aperture problem: e.g. horizontal edges in a rectified pair)
    then score low and are not propagated into.
    """
    img = np.asarray(gray, dtype=np.float64)
    if epipole is None:
        texture = np.zeros_like(img)
        dx = np.abs(np.diff(img, axis=1))
        dy = np.abs(np.diff(img, axis=0))
        texture[:, :-1] = np.maximum(texture[:, :-1], dx)
        texture[:, 1:] = np.maximum(texture[:, 1:], dx)
        texture[:-1, :] = np.maximum(texture[:-1, :], dy)
        texture[1:, :] = np.maximum(texture[1:, :], dy)
        return texture
    g_a, _ = _epipolar_gradients(img, epipole)
    along = np.abs(g_a)
    k = 2 * half_window + 1
    return cv2.boxFilter(along, cv2.CV_64F, (k, k), normalize=True, borderType=cv2.BORDER_REFLECT)


def aperture_coupling(gray: np.ndarray, half_window: int, epipole) -> np.ndarray:
    """How strongly a window's displacement along the epipolar line depends on an error
    across it, per pixel, float64 (H, W) (dimensionless; 0 = independent).

    With ``g_a`` / ``g_n`` the intensity gradient along / across the epipolar line through
    the pixel (direction from the image's epipole, homogeneous 3-vector), summed over the
    ``(2 half_window + 1)``-pixel window: ``|sum g_a g_n| / sum g_a^2``. Matching a window
    with a vertical offset ``dv`` (an integer-pixel match of a pair whose rows differ by a
    fraction of a pixel) shifts the best horizontal position by about ``coupling * dv``: a
    window whose only structure is an edge slanted ``theta`` from the epipolar line has
    coupling ``1 / tan(theta)`` (0 for an edge across the line, 1 at 45 degrees, large for
    edges nearly along it); windows with texture in two directions stay near 0. Where the
    window has no gradient along the line the value is ``inf``.
    """
    img = np.asarray(gray, dtype=np.float64)
    g_a, g_n = _epipolar_gradients(img, epipole)
    k = 2 * half_window + 1
    saa = cv2.boxFilter(g_a * g_a, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_REFLECT)
    san = cv2.boxFilter(g_a * g_n, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_REFLECT)
    out = np.full_like(img, np.inf)
    ok = saa > 1e-9
    out[ok] = np.abs(san[ok]) / saa[ok]
    return out


def window_statistics(gray: np.ndarray, half_window: int, *, epipole=None):
    """Per-pixel window mean, inverse window norm and texture of a grey image.

    Args:
        gray: (H, W) uint8 or float image.
        half_window: ZNCC window is ``(2 * half_window + 1)`` pixels square.
        epipole: the image's epipole for the directional texture (see :func:`texture_map`).

    Returns:
        ``(image, mean, inv_norm, texture)``, float64 (H, W) each: the image as
        float, the window mean, ``1 / sqrt(sum (I - mean)^2)`` over the window
        (0 for flat windows and within ``half_window`` of the border), and the
        texture from :func:`texture_map`.
    """
    img = np.asarray(gray, dtype=np.float64)
    k = 2 * half_window + 1
    n = float(k * k)
    s1 = cv2.boxFilter(img, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    s2 = cv2.boxFilter(img * img, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    mean = s1 / n
    var_sum = s2 - s1 * mean
    inv_norm = np.zeros_like(img)
    ok = var_sum > 1e-6 * n
    inv_norm[ok] = 1.0 / np.sqrt(var_sum[ok])
    inv_norm[:half_window, :] = 0.0
    inv_norm[-half_window:, :] = 0.0
    inv_norm[:, :half_window] = 0.0
    inv_norm[:, -half_window:] = 0.0
    return img, mean, inv_norm, texture_map(img, half_window, epipole=epipole)


@njit(cache=True)
def _zncc(L, R, x, y, xr, yr, hw, mean_l, inv_l, mean_r, inv_r):
    """ZNCC of the (2hw+1)^2 windows centred on left (x, y) and right (xr, yr)."""
    il = inv_l[y, x]
    ir = inv_r[yr, xr]
    if il == 0.0 or ir == 0.0:
        return -1.0
    s = 0.0
    for j in range(-hw, hw + 1):
        for i in range(-hw, hw + 1):
            s += L[y + j, x + i] * R[yr + j, xr + i]
    n = (2 * hw + 1) * (2 * hw + 1)
    return (s - n * mean_l[y, x] * mean_r[yr, xr]) * il * ir


@njit(cache=True)
def zncc_at(L, R, xl, yl, xr, yr, hw, mean_l, inv_l, mean_r, inv_r):
    """ZNCC of many integer pixel pairs (arrays of equal length); -1 outside the valid area."""
    n = len(xl)
    out = np.full(n, -1.0)
    H, W = L.shape
    for k in range(n):
        x, y, a, b = xl[k], yl[k], xr[k], yr[k]
        if hw <= x < W - hw and hw <= y < H - hw and hw <= a < W - hw and hw <= b < H - hw:
            out[k] = _zncc(L, R, x, y, a, b, hw, mean_l, inv_l, mean_r, inv_r)
    return out


# ----------------------------------------------------------------------------------------------
# Binary max-heap on parallel arrays (key: ZNCC, value: match index)


@njit(cache=True)
def _heap_push(keys, vals, size, key, val):
    i = size
    keys[i] = key
    vals[i] = val
    while i > 0:
        p = (i - 1) >> 1
        if keys[p] >= keys[i]:
            break
        keys[p], keys[i] = keys[i], keys[p]
        vals[p], vals[i] = vals[i], vals[p]
        i = p
    return size + 1


@njit(cache=True)
def _heap_pop(keys, vals, size):
    """Remove the top; returns (value, new size)."""
    top = vals[0]
    size -= 1
    keys[0] = keys[size]
    vals[0] = vals[size]
    i = 0
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        c = child
        if child + 1 < size and keys[child + 1] > keys[child]:
            c = child + 1
        if keys[i] >= keys[c]:
            break
        keys[c], keys[i] = keys[i], keys[c]
        vals[c], vals[i] = vals[i], vals[c]
        i = c
    return top, size


# ----------------------------------------------------------------------------------------------
# Propagation


@njit(cache=True)
def _propagate_kernel(L, R, mean_l, inv_l, tex_l, mean_r, inv_r, tex_r, seeds, hw, radius, eps,
                      zncc_min, texture_min, F, band, used_l, used_r):
    """Best-first match propagation; see :func:`propagate`.

    seeds: (S, 4) int64 rows (xl, yl, xr, yr) in decreasing ZNCC order; ``band`` <= 0
    disables the epipolar check with ``F``. ``used_l``/``used_r``: (H, W) bool maps of
    the pixels already matched (by an earlier pass), updated in place. Returns the
    match list arrays (xl, yl, xr, yr, zncc, parent) of this pass, seeds first,
    truncated to the number of matches.
    """
    H, W = L.shape
    cap = seeds.shape[0] + H * W
    mxl = np.empty(cap, np.int32)
    myl = np.empty(cap, np.int32)
    mxr = np.empty(cap, np.int32)
    myr = np.empty(cap, np.int32)
    mz = np.empty(cap, np.float32)
    mparent = np.empty(cap, np.int64)
    hkeys = np.empty(cap, np.float64)
    hvals = np.empty(cap, np.int64)
    hsize = 0
    count = 0
    use_f = band > 0.0
    # seeds: accepted in the given (best-first) order when both pixels are free
    for s in range(seeds.shape[0]):
        x, y, a, b = seeds[s, 0], seeds[s, 1], seeds[s, 2], seeds[s, 3]
        if not (hw <= x < W - hw and hw <= y < H - hw and hw <= a < W - hw and hw <= b < H - hw):
            continue
        if used_l[y, x] or used_r[b, a]:
            continue
        z = _zncc(L, R, x, y, a, b, hw, mean_l, inv_l, mean_r, inv_r)
        if z < zncc_min:
            continue
        used_l[y, x] = True
        used_r[b, a] = True
        mxl[count] = x
        myl[count] = y
        mxr[count] = a
        myr[count] = b
        mz[count] = z
        mparent[count] = -1
        hsize = _heap_push(hkeys, hvals, hsize, z, count)
        count += 1
    n_nb = (2 * radius + 1) * (2 * radius + 1) * (2 * eps + 1) * (2 * eps + 1)
    n_eps = (2 * eps + 1) * (2 * eps + 1)
    cache_dx = np.full((H, W), -(1 << 30), np.int32)
    cache_dy = np.full((H, W), -(1 << 30), np.int32)
    cache_z = np.empty((H, W, n_eps), np.float32)
    cz = np.empty(n_nb, np.float64)
    cu = np.empty(n_nb, np.int32)
    cv = np.empty(n_nb, np.int32)
    ca = np.empty(n_nb, np.int32)
    cb = np.empty(n_nb, np.int32)
    while hsize > 0:
        m, hsize = _heap_pop(hkeys, hvals, hsize)
        x, y, a, b = mxl[m], myl[m], mxr[m], myr[m]
        dx = a - x
        dy = b - y
        nc = 0
        for j in range(-radius, radius + 1):
            v = y + j
            if v < hw or v >= H - hw:
                continue
            for i in range(-radius, radius + 1):
                u = x + i
                if u < hw or u >= W - hw or used_l[v, u] or tex_l[v, u] <= texture_min:
                    continue
                if use_f:
                    l0 = F[0, 0] * u + F[0, 1] * v + F[0, 2]
                    l1 = F[1, 0] * u + F[1, 1] * v + F[1, 2]
                    l2 = F[2, 0] * u + F[2, 1] * v + F[2, 2]
                    lnorm = np.sqrt(l0 * l0 + l1 * l1)
                # ZNCC of the (2 eps + 1)^2 candidates of u for this displacement, cached per
                # left pixel: u is usually reached again from a neighbour with the same one
                fresh = cache_dx[v, u] != dx or cache_dy[v, u] != dy
                if fresh:
                    cache_dx[v, u] = dx
                    cache_dy[v, u] = dy
                e = 0
                for jj in range(-eps, eps + 1):
                    vr = v + dy + jj
                    for ii in range(-eps, eps + 1):
                        ur = u + dx + ii
                        if fresh:
                            z = -2.0                      # fails a static test
                            if (hw <= vr < H - hw and hw <= ur < W - hw
                                    and tex_r[vr, ur] > texture_min
                                    and (not use_f or abs(l0 * ur + l1 * vr + l2) <= band * lnorm)):
                                z = _zncc(L, R, u, v, ur, vr, hw, mean_l, inv_l, mean_r, inv_r)
                            cache_z[v, u, e] = z
                        z = cache_z[v, u, e]
                        e += 1
                        if z < zncc_min or used_r[vr, ur]:
                            continue
                        # insertion into the local list, kept in decreasing ZNCC order
                        k = nc
                        while k > 0 and cz[k - 1] < z:
                            cz[k] = cz[k - 1]
                            cu[k] = cu[k - 1]
                            cv[k] = cv[k - 1]
                            ca[k] = ca[k - 1]
                            cb[k] = cb[k - 1]
                            k -= 1
                        cz[k] = z
                        cu[k] = u
                        cv[k] = v
                        ca[k] = ur
                        cb[k] = vr
                        nc += 1
        for k in range(nc):
            u, v, ur, vr = cu[k], cv[k], ca[k], cb[k]
            if used_l[v, u] or used_r[vr, ur]:
                continue
            used_l[v, u] = True
            used_r[vr, ur] = True
            mxl[count] = u
            myl[count] = v
            mxr[count] = ur
            myr[count] = vr
            mz[count] = cz[k]
            mparent[count] = m
            hsize = _heap_push(hkeys, hvals, hsize, cz[k], count)
            count += 1
    return (mxl[:count].copy(), myl[:count].copy(), mxr[:count].copy(), myr[:count].copy(),
            mz[:count].copy(), mparent[:count].copy())


@njit(cache=True)
def _search_line(A, B, mean_a, inv_a, mean_b, inv_b, x, y, l0, l1, l2, dx_lo, dx_hi, dy_lo, dy_hi,
                 hw, zs, xs, ys):
    """ZNCC of A's window at (x, y) against every integer pixel of B on the line
    ``l0 u + l1 v + l2 = 0`` whose displacement from (x, y) is within the ranges.

    Fills ``zs``/``xs``/``ys`` (candidates in order along the line) and returns
    their number.
    """
    H, W = A.shape
    n = 0
    if abs(l1) >= abs(l0):                      # mostly horizontal: step along u
        for xb in range(x + dx_lo, x + dx_hi + 1):
            yb = int(np.floor(-(l0 * xb + l2) / l1 + 0.5))
            if yb - y < dy_lo or yb - y > dy_hi:
                continue
            if not (hw <= xb < W - hw and hw <= yb < H - hw):
                continue
            zs[n] = _zncc(A, B, x, y, xb, yb, hw, mean_a, inv_a, mean_b, inv_b)
            xs[n] = xb
            ys[n] = yb
            n += 1
    else:                                       # mostly vertical: step along v
        for yb in range(y + dy_lo, y + dy_hi + 1):
            xb = int(np.floor(-(l1 * yb + l2) / l0 + 0.5))
            if xb - x < dx_lo or xb - x > dx_hi:
                continue
            if not (hw <= xb < W - hw and hw <= yb < H - hw):
                continue
            zs[n] = _zncc(A, B, x, y, xb, yb, hw, mean_a, inv_a, mean_b, inv_b)
            xs[n] = xb
            ys[n] = yb
            n += 1
    return n


@njit(cache=True)
def _distinct_best(zs, n, exclude):
    """Index of the best of ``zs[:n]`` and the best value more than ``exclude``
    candidates away from it (the runner-up peak; -1 when there is none)."""
    best = -1
    for k in range(n):
        if best < 0 or zs[k] > zs[best]:
            best = k
    second = -1.0
    for k in range(n):
        if abs(k - best) > exclude and zs[k] > second:
            second = zs[k]
    return best, second


@njit(cache=True)
def _epipolar_seed_kernel(L, R, mean_l, inv_l, mean_r, inv_r, cand, F, dx_lo, dx_hi, dy_lo,
                          dy_hi, hw, zncc_min, margin, used_r):
    """Seeds for regions the propagation did not reach: for each candidate left pixel,
    the best ZNCC along its epipolar line within the displacement ranges, kept when it
    reaches ``zncc_min``, beats every other peak on the line by ``margin`` and the
    search back from the right pixel along its own epipolar line returns to within
    1 px of the left pixel. Returns (K, 5) float64 rows (xl, yl, xr, yr, zncc).
    """
    n_c = cand.shape[0]
    span = max(dx_hi - dx_lo, dy_hi - dy_lo) + 1
    zs = np.empty(span)
    xs = np.empty(span, np.int64)
    ys = np.empty(span, np.int64)
    out = np.empty((n_c, 5))
    k_out = 0
    for c in range(n_c):
        x, y = cand[c, 0], cand[c, 1]
        l0 = F[0, 0] * x + F[0, 1] * y + F[0, 2]
        l1 = F[1, 0] * x + F[1, 1] * y + F[1, 2]
        l2 = F[2, 0] * x + F[2, 1] * y + F[2, 2]
        if abs(l0) + abs(l1) < 1e-12:
            continue
        n = _search_line(L, R, mean_l, inv_l, mean_r, inv_r, x, y, l0, l1, l2, dx_lo, dx_hi,
                         dy_lo, dy_hi, hw, zs, xs, ys)
        if n == 0:
            continue
        b, second = _distinct_best(zs, n, 2)
        zb = zs[b]
        if zb < zncc_min or zb - second < margin:
            continue
        xb, yb = xs[b], ys[b]
        if used_r[yb, xb]:
            continue
        # back from the right pixel along its epipolar line in the left image
        m0 = F[0, 0] * xb + F[1, 0] * yb + F[2, 0]
        m1 = F[0, 1] * xb + F[1, 1] * yb + F[2, 1]
        m2 = F[0, 2] * xb + F[1, 2] * yb + F[2, 2]
        if abs(m0) + abs(m1) < 1e-12:
            continue
        n = _search_line(R, L, mean_r, inv_r, mean_l, inv_l, xb, yb, m0, m1, m2, -dx_hi, -dx_lo,
                         -dy_hi, -dy_lo, hw, zs, xs, ys)
        if n == 0:
            continue
        b2, _ = _distinct_best(zs, n, 2)
        if abs(xs[b2] - x) > 1 or abs(ys[b2] - y) > 1:
            continue
        out[k_out, 0] = x
        out[k_out, 1] = y
        out[k_out, 2] = xb
        out[k_out, 3] = yb
        out[k_out, 4] = zb
        k_out += 1
    return out[:k_out].copy()


def epipolar_seeds(left_gray: np.ndarray, right_gray: np.ndarray, F: np.ndarray, candidates,
                   displacement_box, *, half_window: int = 3, zncc_min: float = 0.9,
                   margin: float = 0.1, used_right: np.ndarray | None = None,
                   stats=None) -> np.ndarray:
    """Matches found by a 1-D ZNCC search along epipolar lines (seeds for unreached regions).

    Args:
        left_gray, right_gray: (H, W) grey images of the same size.
        F: (3, 3) fundamental matrix, ``x_r^T F x_l = 0``.
        candidates: (C, 2) integer left pixels ``(u, v)`` to find matches for.
        displacement_box: ``(dx_lo, dx_hi, dy_lo, dy_hi)`` integer pixels: the right pixel
            ``(u', v')`` must satisfy ``dx_lo <= u' - u <= dx_hi`` and ``dy_lo <= v' - v <= dy_hi``.
        half_window: the search's ZNCC window is ``2 * half_window + 1`` pixels square.
        zncc_min: correlation the best candidate must reach.
        margin: it must beat every other peak on the line (more than 2 px away) by this.
        used_right: optional (H, W) bool map of right pixels that are taken already.
        stats: precomputed ``(window_statistics(left), window_statistics(right))`` at
            ``half_window``.

    Returns:
        (K, 5) float64 rows ``(u, v, u', v', zncc)``, left-right consistent to 1 px.
    """
    if half_window < 1:
        raise CanopyStereoError(f"half_window must be >= 1, got {half_window}")
    if stats is None:
        stats = (window_statistics(left_gray, half_window), window_statistics(right_gray, half_window))
    (L, mean_l, inv_l, _), (R, mean_r, inv_r, _) = stats
    cand = np.ascontiguousarray(np.asarray(candidates, np.int64).reshape(-1, 2))
    if used_right is None:
        used_right = np.zeros(L.shape, np.bool_)
    dx_lo, dx_hi, dy_lo, dy_hi = (int(v) for v in displacement_box)
    if dx_hi < dx_lo or dy_hi < dy_lo or len(cand) == 0:
        return np.zeros((0, 5))
    return _epipolar_seed_kernel(L, R, mean_l, inv_l, mean_r, inv_r, cand,
                                 np.asarray(F, np.float64), dx_lo, dx_hi, dy_lo, dy_hi,
                                 int(half_window), float(zncc_min), float(margin),
                                 np.ascontiguousarray(used_right, dtype=np.bool_))


@dataclass
class Propagation:
    """Pixel matches grown from the seeds.

    Attributes:
        x_left, x_right: (M, 2) int32 integer pixels ``(u, v)`` of each match.
        zncc: (M,) float32 window correlation of each match.
        parent: (M,) int64 index of the match it was propagated from (-1 for seeds).
        num_seeds: how many seeds were accepted (they come first in the arrays).
        image_size: ``(width, height)``.
        params: the propagation parameters used (``radius``, ``eps``, ...).
    """

    x_left: np.ndarray
    x_right: np.ndarray
    zncc: np.ndarray
    parent: np.ndarray
    num_seeds: int
    image_size: tuple
    params: dict

    def __len__(self) -> int:
        return len(self.x_left)

    def match_map(self) -> np.ndarray:
        """(H, W, 2) int32: the right pixel matched to each left pixel, -1 where none."""
        w, h = self.image_size
        out = np.full((h, w, 2), -1, np.int32)
        out[self.x_left[:, 1], self.x_left[:, 0]] = self.x_right
        return out


def propagate(left_gray: np.ndarray, right_gray: np.ndarray, seeds_left, seeds_right, *,
              half_window: int = 2, radius: int = 1, eps: int = 1, zncc_min: float = 0.8,
              texture_min: float = 2.0, F: np.ndarray | None = None,
              epipolar_band_px: float | None = 1.0, directional_texture: bool = True,
              reseed_rounds: int = 2, reseed_step_px: int = 4, reseed_gap_px: int = 3,
              reseed_half_window: int = 3, reseed_zncc_min: float = 0.9,
              reseed_margin: float = 0.1, aperture_max: float | None = None,
              stats=None) -> Propagation:
    """Grow pixel matches from seeds, best ZNCC first (Lhuillier & Quan's propagation).

    Args:
        left_gray, right_gray: uint8 (H, W) images.
        seeds_left, seeds_right: (S, 2) seed matches in pixels (rounded to whole pixels).
        half_window: ZNCC window is ``2 * half_window + 1`` pixels square.
        radius: neighbourhood ``N(x)`` of a match is ``(2 radius + 1)^2`` left pixels.
        eps: disparity-gradient limit: a new match's displacement ``u' - u`` differs
            from its parent's by at most ``eps`` pixels in each coordinate.
        zncc_min: correlation threshold for a candidate.
        texture_min: minimum texture of the window in both images (grey levels per
            pixel, see :func:`texture_map`).
        F: optional (3, 3) fundamental matrix (``x_r^T F x_l = 0``); with
            ``epipolar_band_px`` a candidate must lie that close to its epipolar line.
        epipolar_band_px: band half-width in pixels; None or 0 disables the check.
        directional_texture: with F, measure texture along the epipolar lines
            (rejects aperture-ambiguous windows) instead of the 4-neighbour measure.
        reseed_rounds: with F, up to this many more passes grow from new seeds in the
            textured regions the earlier passes did not reach (leaves with no SIFT
            match of their own): left pixels on a ``reseed_step_px`` grid, with texture,
            at least ``reseed_gap_px`` from every matched pixel, matched by a ZNCC search
            along their epipolar line within the displacements seen so far (window
            ``2 reseed_half_window + 1``, best >= ``reseed_zncc_min``, ahead of any
            other peak by ``reseed_margin``, left-right consistent). 0: SIFT seeds only.
        aperture_max: with F, pixels (left and right) whose window's
            :func:`aperture_coupling` exceeds this are treated as untextured (not
            propagated into); None: no limit.
        stats: precomputed ``(window_statistics(left), window_statistics(right))``.

    Returns:
        :class:`Propagation`; every left pixel and every right pixel is used at most
        once. Seeds (of every pass) come first, then the grown matches in the order
        they were accepted, so a match's parent always precedes it.
    """
    if half_window < 1 or radius < 1 or eps < 0:
        raise CanopyStereoError("half_window and radius must be >= 1 and eps >= 0")
    if reseed_rounds < 0 or reseed_step_px < 1 or reseed_gap_px < 0:
        raise CanopyStereoError("reseed_rounds and reseed_gap_px must be >= 0, reseed_step_px >= 1")
    h, w = left_gray.shape[:2]
    if stats is None:
        e_l = e_r = None
        if F is not None and directional_texture:
            e_l, e_r = epipoles(np.asarray(F, np.float64))
        stats = (window_statistics(left_gray, half_window, epipole=e_l),
                 window_statistics(right_gray, half_window, epipole=e_r))
    (L, mean_l, inv_l, tex_l), (R, mean_r, inv_r, tex_r) = stats
    if aperture_max is not None and F is not None:
        e_l, e_r = epipoles(np.asarray(F, np.float64))
        tex_l = np.where(aperture_coupling(L, half_window, e_l) <= aperture_max, tex_l, 0.0)
        tex_r = np.where(aperture_coupling(R, half_window, e_r) <= aperture_max, tex_r, 0.0)
    sl = np.rint(np.asarray(seeds_left, np.float64).reshape(-1, 2)).astype(np.int64)
    sr = np.rint(np.asarray(seeds_right, np.float64).reshape(-1, 2)).astype(np.int64)
    seeds = np.column_stack([sl, sr]).astype(np.int64) if len(sl) else np.zeros((0, 4), np.int64)
    # seeds in decreasing ZNCC order (the kernel accepts them in this order)
    if len(seeds):
        z = zncc_at(L, R, seeds[:, 0], seeds[:, 1], seeds[:, 2], seeds[:, 3], half_window,
                    mean_l, inv_l, mean_r, inv_r)
        seeds = np.ascontiguousarray(seeds[np.argsort(-z, kind="stable")])
    use_band = F is not None and epipolar_band_px is not None and epipolar_band_px > 0
    Fk = np.asarray(F, np.float64) if use_band else np.eye(3)
    band = float(epipolar_band_px) if use_band else 0.0
    used_l = np.zeros((h, w), np.bool_)
    used_r = np.zeros((h, w), np.bool_)

    def run(pass_seeds):
        return _propagate_kernel(L, R, mean_l, inv_l, tex_l, mean_r, inv_r, tex_r, pass_seeds,
                                 int(half_window), int(radius), int(eps), float(zncc_min),
                                 float(texture_min), Fk, band, used_l, used_r)

    passes = [run(seeds)]
    num_reseeded = 0
    if F is not None and reseed_rounds > 0:
        F64 = np.asarray(F, np.float64)
        seed_stats = None
        for _ in range(int(reseed_rounds)):
            box = _displacement_box(np.concatenate([p[0] for p in passes]),
                                    np.concatenate([p[1] for p in passes]),
                                    np.concatenate([p[2] for p in passes]),
                                    np.concatenate([p[3] for p in passes]))
            if box is None:
                break
            cand = _reseed_candidates(tex_l, inv_l, used_l, texture_min, reseed_step_px,
                                      reseed_gap_px, reseed_half_window)
            if len(cand) == 0:
                break
            if seed_stats is None:
                seed_stats = (window_statistics(L, reseed_half_window),
                              window_statistics(R, reseed_half_window))
            found = epipolar_seeds(L, R, F64, cand, box, half_window=reseed_half_window,
                                   zncc_min=reseed_zncc_min, margin=reseed_margin,
                                   used_right=used_r, stats=seed_stats)
            if len(found) == 0:
                break
            new_seeds = np.rint(found[:, :4]).astype(np.int64)
            z = zncc_at(L, R, new_seeds[:, 0], new_seeds[:, 1], new_seeds[:, 2], new_seeds[:, 3],
                        half_window, mean_l, inv_l, mean_r, inv_r)
            new_seeds = np.ascontiguousarray(new_seeds[np.argsort(-z, kind="stable")])
            res = run(new_seeds)
            if len(res[0]) == 0:
                break
            num_reseeded += int(np.sum(res[5] < 0))
            passes.append(res)
    xl, yl, xr, yr, zz, parent = _merge_passes(passes)
    num_seeds = int(np.sum(parent < 0))
    params = dict(half_window=half_window, radius=radius, eps=eps, zncc_min=zncc_min,
                  texture_min=texture_min, epipolar_band_px=band if use_band else None,
                  reseed_rounds=reseed_rounds, num_reseeded=num_reseeded)
    return Propagation(np.column_stack([xl, yl]), np.column_stack([xr, yr]), zz, parent,
                       num_seeds, (w, h), params)


def _displacement_box(xl, yl, xr, yr, min_matches: int = 20):
    """Integer ``(dx_lo, dx_hi, dy_lo, dy_hi)`` covering the displacements of the
    matches so far (0.5-99.5th percentiles widened by a tenth of their span + 2 px);
    None with fewer than ``min_matches`` matches."""
    if len(xl) < min_matches:
        return None
    box = []
    for d in (xr.astype(np.float64) - xl, yr.astype(np.float64) - yl):
        lo, hi = np.percentile(d, [0.5, 99.5])
        pad = 0.1 * (hi - lo) + 2.0
        box += [int(np.floor(lo - pad)), int(np.ceil(hi + pad))]
    return tuple(box)


def _reseed_candidates(tex_l, inv_l, used_l, texture_min, step, gap, half_window):
    """(C, 2) int64 left pixels on a ``step`` grid with texture, a non-flat search
    window, and at least ``gap`` pixels from every matched left pixel."""
    h, w = used_l.shape
    far = ~used_l
    if gap > 0:
        k = 2 * gap + 1
        near = cv2.dilate(used_l.astype(np.uint8), np.ones((k, k), np.uint8)) > 0
        far = ~near
    m = half_window + 1
    grid = np.zeros((h, w), bool)
    grid[m:h - m:step, m:w - m:step] = True
    ok = grid & far & (tex_l > texture_min) & (inv_l > 0)
    v, u = np.nonzero(ok)
    return np.column_stack([u, v]).astype(np.int64)


def _merge_passes(passes):
    """Concatenate propagation passes as one match list: every pass's seeds first, then
    the grown matches pass by pass, parent indices remapped (a parent precedes its child)."""
    if len(passes) == 1:
        return passes[0]
    order, offset = [], 0
    for p in passes:
        order.append(offset + np.nonzero(p[5] < 0)[0])
        offset += len(p[0])
    offset = 0
    for p in passes:
        order.append(offset + np.nonzero(p[5] >= 0)[0])
        offset += len(p[0])
    order = np.concatenate(order)
    cols = [np.concatenate([p[i] for p in passes]) for i in range(5)]
    parent = np.concatenate([np.where(p[5] >= 0, p[5] + off, -1) for p, off in
                             zip(passes, np.cumsum([0] + [len(p[0]) for p in passes[:-1]]))])
    new_index = np.empty(len(order), np.int64)
    new_index[order] = np.arange(len(order))
    parent = parent[order]
    parent = np.where(parent >= 0, new_index[np.maximum(parent, 0)], -1)
    return tuple(c[order] for c in cols) + (parent,)


# ----------------------------------------------------------------------------------------------
# Resampling


@njit(cache=True)
def _lcg(state):
    """One step of a 64-bit linear congruential generator: (new state, value in [0, 2^31))."""
    state = state * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
    return state, np.int64(state >> np.uint64(33))


@njit(cache=True)
def _fit_affine(px, py, qx, qy, idx, n):
    """Least-squares affine map p -> q over points idx[:n]: (2, 3) array; ok flag."""
    A = np.zeros((3, 3))
    bx = np.zeros(3)
    by = np.zeros(3)
    for k in range(n):
        i = idx[k]
        r0, r1 = px[i], py[i]
        A[0, 0] += r0 * r0
        A[0, 1] += r0 * r1
        A[0, 2] += r0
        A[1, 1] += r1 * r1
        A[1, 2] += r1
        A[2, 2] += 1.0
        bx[0] += r0 * qx[i]
        bx[1] += r1 * qx[i]
        bx[2] += qx[i]
        by[0] += r0 * qy[i]
        by[1] += r1 * qy[i]
        by[2] += qy[i]
    A[1, 0] = A[0, 1]
    A[2, 0] = A[0, 2]
    A[2, 1] = A[1, 2]
    M = np.zeros((2, 3))
    det = np.linalg.det(A)
    if abs(det) < 1e-9 * max(1.0, A[2, 2]) ** 3:
        return M, False
    M[0] = np.linalg.solve(A, bx)
    M[1] = np.linalg.solve(A, by)
    return M, True


@njit(cache=True)
def _fit_homography(px, py, qx, qy, idx, n, cx, cy):
    """Least-squares (DLT, centred on (cx, cy)) homography p -> q over idx[:n]: (3, 3); ok."""
    A = np.zeros((2 * n, 9))
    for k in range(n):
        i = idx[k]
        x, y = px[i] - cx, py[i] - cy
        u, v = qx[i] - cx, qy[i] - cy
        A[2 * k, 0] = x
        A[2 * k, 1] = y
        A[2 * k, 2] = 1.0
        A[2 * k, 6] = -u * x
        A[2 * k, 7] = -u * y
        A[2 * k, 8] = -u
        A[2 * k + 1, 3] = x
        A[2 * k + 1, 4] = y
        A[2 * k + 1, 5] = 1.0
        A[2 * k + 1, 6] = -v * x
        A[2 * k + 1, 7] = -v * y
        A[2 * k + 1, 8] = -v
    _, s, vt = np.linalg.svd(A)
    Hc = np.ascontiguousarray(vt[8]).reshape(3, 3)
    if abs(Hc[2, 2]) < 1e-12 or s[7] < 1e-9 * s[0]:
        return np.eye(3), False
    # undo the centring: H = T^-1 Hc T with T = translate(-c)
    T = np.eye(3)
    T[0, 2] = -cx
    T[1, 2] = -cy
    Ti = np.eye(3)
    Ti[0, 2] = cx
    Ti[1, 2] = cy
    H = Ti @ Hc @ T
    return H / H[2, 2], True


@njit(cache=True)
def _map_point(model, use_h, x, y):
    if use_h:
        w = model[2, 0] * x + model[2, 1] * y + model[2, 2]
        if abs(w) < 1e-12:
            return 1e30, 1e30
        return ((model[0, 0] * x + model[0, 1] * y + model[0, 2]) / w,
                (model[1, 0] * x + model[1, 1] * y + model[1, 2]) / w)
    return (model[0, 0] * x + model[0, 1] * y + model[0, 2],
            model[1, 0] * x + model[1, 1] * y + model[1, 2])


@njit(cache=True)
def _consistent(match_map, model, use_h, u, v, tol):
    """Pixel (u, v) is inside the image, matched, and its match within ``tol`` of the map."""
    H, W = match_map.shape[0], match_map.shape[1]
    if u < 0 or u >= W or v < 0 or v >= H or match_map[v, u, 0] < 0:
        return False
    mx, my = _map_point(model, use_h, u, v)
    return abs(mx - match_map[v, u, 0]) <= tol and abs(my - match_map[v, u, 1]) <= tol


@njit(cache=True)
def _interior(match_map, model, use_h, u, v, r, tol, shape, epipole):
    """Every pixel within ``r`` of (u, v) -- along the epipolar line through it (shape 0;
    ``epipole`` homogeneous, (0, 0, 0) = the image rows), along the line and the image
    column (1: cross) or in the square (2) -- is matched consistently with the map."""
    if shape == 0:
        ex, ey, ew = epipole[0], epipole[1], epipole[2]
        dx, dy = 1.0, 0.0
        if ex != 0.0 or ey != 0.0 or ew != 0.0:
            dx = ew * u - ex
            dy = ew * v - ey
            n = np.sqrt(dx * dx + dy * dy)
            if n < 1e-12:
                return False
            dx /= n
            dy /= n
        for k in range(-r, r + 1):
            uu = int(np.floor(u + k * dx + 0.5))
            vv = int(np.floor(v + k * dy + 0.5))
            if not _consistent(match_map, model, use_h, uu, vv, tol):
                return False
        return True
    for jj in range(-r, r + 1):
        for ii in range(-r, r + 1):
            if shape == 1 and jj != 0 and ii != 0:
                continue
            if not _consistent(match_map, model, use_h, u + ii, v + jj, tol):
                return False
    return True


@njit(cache=True)
def _resample_kernel(match_map, cell, use_h, iters, tol, min_support, min_share, min_spread, seed,
                     anchor_centroid, thin_spread, conflict_pad, conflict_px, interior, interior_tol,
                     interior_shape, anchor_ok, epipole):
    """One match per cell of the left image from a local affine/homography RANSAC fit.

    Returns (K, 4) float64 rows (u_left, v_left, u_right, v_right) and (K,) inlier counts.
    """
    H, W = match_map.shape[0], match_map.shape[1]
    ny = (H + cell - 1) // cell
    nx = (W + cell - 1) // cell
    out = np.empty((nx * ny, 4))
    support = np.empty(nx * ny, np.int64)
    nout = 0
    px = np.empty(cell * cell)
    py = np.empty(cell * cell)
    qx = np.empty(cell * cell)
    qy = np.empty(cell * cell)
    idx = np.empty(cell * cell, np.int64)
    best_idx = np.empty(cell * cell, np.int64)
    sample = np.empty(4, np.int64)
    k_min = 4 if use_h else 3
    state = np.uint64(seed)
    for cyi in range(ny):
        for cxi in range(nx):
            x0, y0 = cxi * cell, cyi * cell
            x1, y1 = min(x0 + cell, W), min(y0 + cell, H)
            n = 0
            for v in range(y0, y1):
                for u in range(x0, x1):
                    if match_map[v, u, 0] >= 0:
                        px[n] = u
                        py[n] = v
                        qx[n] = match_map[v, u, 0]
                        qy[n] = match_map[v, u, 1]
                        n += 1
            if n < min_support or n < k_min + 1:
                continue
            ccx = 0.5 * (x0 + x1 - 1)
            ccy = 0.5 * (y0 + y1 - 1)
            best = 0
            for _it in range(iters):
                # draw k_min distinct points
                for s in range(k_min):
                    while True:
                        state, r = _lcg(state)
                        c = r % n
                        dup = False
                        for t in range(s):
                            if sample[t] == c:
                                dup = True
                        if not dup:
                            break
                    sample[s] = c
                if use_h:
                    model, ok = _fit_homography(px, py, qx, qy, sample, k_min, ccx, ccy)
                else:
                    m2, ok = _fit_affine(px, py, qx, qy, sample, k_min)
                    model = np.zeros((3, 3))
                    model[:2] = m2
                    model[2, 2] = 1.0
                if not ok:
                    continue
                ni = 0
                for k in range(n):
                    mx, my = _map_point(model, use_h, px[k], py[k])
                    if abs(mx - qx[k]) <= tol and abs(my - qy[k]) <= tol:
                        idx[ni] = k
                        ni += 1
                if ni > best:
                    best = ni
                    best_idx[:ni] = idx[:ni]
                    if ni == n:
                        break
            if best < min_support or best < min_share * n:
                continue
            # the inliers must surround the centre (interpolation, not extrapolation)
            q0 = q1 = q2 = q3 = 0
            for k in range(best):
                i = best_idx[k]
                if px[i] < ccx:
                    if py[i] < ccy:
                        q0 += 1
                    else:
                        q1 += 1
                elif py[i] < ccy:
                    q2 += 1
                else:
                    q3 += 1
            surrounded = q0 > 0 and q1 > 0 and q2 > 0 and q3 > 0
            if not surrounded and not anchor_centroid:
                continue
            # ... and cover an area, not a thin line (an edge: the aperture problem, and
            # typically an occlusion boundary): minor standard deviation of the inliers
            sx = sy = 0.0
            for k in range(best):
                sx += px[best_idx[k]]
                sy += py[best_idx[k]]
            sx /= best
            sy /= best
            cxx = cyy = cxy = 0.0
            for k in range(best):
                ddx = px[best_idx[k]] - sx
                ddy = py[best_idx[k]] - sy
                cxx += ddx * ddx
                cyy += ddy * ddy
                cxy += ddx * ddy
            cxx /= best
            cyy /= best
            cxy /= best
            minor = 0.5 * (cxx + cyy) - np.sqrt(0.25 * (cxx - cyy) ** 2 + cxy * cxy)
            thin = minor < min_spread * min_spread
            if thin and minor < thin_spread * thin_spread:
                continue
            # refit on the inliers and map the cell centre
            if use_h:
                model, ok = _fit_homography(px, py, qx, qy, best_idx, best, ccx, ccy)
            else:
                m2, ok = _fit_affine(px, py, qx, qy, best_idx, best)
                model = np.zeros((3, 3))
                model[:2] = m2
                model[2, 2] = 1.0
            if not ok:
                continue
            if thin:
                # a thin set of inliers is kept only on one surface: no propagated match
                # around the cell (within conflict_pad px) may disagree with its map
                conflict = False
                for v in range(max(0, y0 - conflict_pad), min(H, y1 + conflict_pad)):
                    for u in range(max(0, x0 - conflict_pad), min(W, x1 + conflict_pad)):
                        if match_map[v, u, 0] >= 0:
                            mx, my = _map_point(model, use_h, u, v)
                            if (abs(mx - match_map[v, u, 0]) > conflict_px
                                    or abs(my - match_map[v, u, 1]) > conflict_px):
                                conflict = True
                                break
                    if conflict:
                        break
                if conflict:
                    continue
            ax, ay = ccx, ccy
            if not surrounded:
                ax, ay = sx, sy                 # the inliers' centroid: inside their support
            if interior > 0:
                # the inlier nearest that point whose neighbourhood is matched consistently
                # with the fit (see resample's interior_px)
                bd = 1e30
                found = False
                bx = by = 0.0
                for k in range(best):
                    i = best_idx[k]
                    iu, iv = int(px[i]), int(py[i])
                    dd = (px[i] - ax) ** 2 + (py[i] - ay) ** 2
                    if dd >= bd or not anchor_ok[iv, iu]:
                        continue
                    if _interior(match_map, model, use_h, iu, iv, interior, interior_tol,
                                 interior_shape, epipole):
                        bd = dd
                        found = True
                        bx, by = px[i], py[i]
                if not found:
                    continue
                ax, ay = bx, by
            mx, my = _map_point(model, use_h, ax, ay)
            if not (-0.5 <= mx < W - 0.5 and -0.5 <= my < H - 0.5):
                continue
            out[nout, 0] = ax
            out[nout, 1] = ay
            out[nout, 2] = mx
            out[nout, 3] = my
            support[nout] = best
            nout += 1
    return out[:nout].copy(), support[:nout].copy()


def resample(prop: Propagation, *, cell_px: int = DISTRIBUTION_CELL_PX, model: str = "affine",
             iters: int = 32, tol_px: float = 1.0, min_support: int = 12,
             min_inlier_share: float = 0.85, min_spread_px: float = 1.8, seed: int = 12345,
             anchor: str = "centre", thin_spread_px: float | None = None,
             conflict_pad_px: int = 4, conflict_px: float = 2.0, interior_px: int = 0,
             interior_tol_px: float = 1.0, interior_shape: str = "line", anchor_mask=None,
             epipole=None):
    """One match per ``cell_px`` x ``cell_px`` left region from a local RANSAC fit.

    Args:
        prop: propagated matches.
        cell_px: region side in pixels (8 = the distribution cells).
        model: ``"affine"`` (6 dof, 3-point samples) or ``"homography"`` (8 dof, 4 points).
        iters: RANSAC iterations per region.
        tol_px: inlier tolerance (each coordinate), pixels.
        min_support: fewest propagated matches (and inliers) a region needs.
        min_inlier_share: the fit must explain this share of the region's matches.
        min_spread_px: the inliers' smaller standard deviation (pixels) must reach
            this, so a region matched only along a line (an edge) emits nothing.
        seed: RNG seed (results are deterministic).
        The defaults are Lhuillier & Quan's resampling; :func:`qdmatch` relaxes them
        (centroid anchors, thin single-surface regions) to reach every textured region.
        anchor: where a region's match is placed: ``"centre"`` (Lhuillier & Quan: only
            regions whose inliers surround the centre emit a match), ``"centroid"``
            (the centre when surrounded, else the inliers' centroid, so regions cut by
            a leaf edge still emit a match inside their support).
        thin_spread_px: inliers spread less than ``min_spread_px`` are still accepted
            down to this spread when no propagated match within ``conflict_pad_px`` of
            the region disagrees with its map by more than ``conflict_px`` (one
            surface, not an occlusion edge); None: same as ``min_spread_px``.
        conflict_pad_px, conflict_px: that neighbourhood (pixels) and tolerance (pixels).
        interior_px: > 0: a region's match is placed on the inlier nearest its centre
            (or centroid) whose neighbours within ``interior_px`` pixels are all matched
            within ``interior_tol_px`` of the region's map; a region without such an
            inlier emits nothing. With ``interior_px`` above the ZNCC half-window this
            keeps matches off the band a window-based match smears past a depth edge
            (the foreground's displacement given to background pixels next to it), the
            main source of wrong matches on Middlebury. 0: off (Lhuillier & Quan).
        interior_tol_px: that tolerance, pixels (each coordinate).
        interior_shape: the neighbours checked: ``"line"`` (along the epipolar line
            through the inlier, the direction a depth edge smears matches; the image row
            without ``epipole``), ``"cross"`` (that line and the image column) or
            ``"square"`` (the whole square).
        anchor_mask: optional (H, W) bool: pixels allowed as the placed match (e.g.
            windows that are not aperture-ambiguous, see :func:`aperture_coupling`).
        epipole: the left epipole (homogeneous 3-vector, ``F e = 0``) for ``"line"``.

    Returns:
        ``(x_left, x_right, support)``: (K, 2) float64 region anchors (centres or
        centroids, see ``anchor``) and their mapped right points, and (K,) inlier counts.
    """
    if model not in ("affine", "homography"):
        raise CanopyStereoError(f"unknown resampling model {model!r}; choose affine or homography")
    if anchor not in ("centre", "centroid"):
        raise CanopyStereoError(f"unknown resampling anchor {anchor!r}; choose centre or centroid")
    if cell_px < 2:
        raise CanopyStereoError(f"cell_px must be >= 2, got {cell_px}")
    shapes = {"line": 0, "cross": 1, "square": 2}
    if interior_shape not in shapes:
        raise CanopyStereoError(f"unknown interior_shape {interior_shape!r}; choose line, cross or square")
    if interior_px < 0 or interior_tol_px < 0:
        raise CanopyStereoError("interior_px and interior_tol_px must be >= 0")
    mm = prop.match_map()
    if anchor_mask is None:
        anchor_mask = np.ones(mm.shape[:2], np.bool_)
    anchor_mask = np.ascontiguousarray(anchor_mask, dtype=np.bool_)
    if anchor_mask.shape != mm.shape[:2]:
        raise CanopyStereoError(f"anchor_mask is {anchor_mask.shape[1]}x{anchor_mask.shape[0]} "
                                f"but the image is {mm.shape[1]}x{mm.shape[0]}")
    e = np.zeros(3) if epipole is None else np.asarray(epipole, np.float64).ravel()[:3]
    rows, support = _resample_kernel(mm, int(cell_px), model == "homography", int(iters),
                                     float(tol_px), int(min_support), float(min_inlier_share),
                                     float(min_spread_px), int(seed), anchor == "centroid",
                                     float(min_spread_px if thin_spread_px is None else thin_spread_px),
                                     int(conflict_pad_px), float(conflict_px), int(interior_px),
                                     float(interior_tol_px), shapes[interior_shape], anchor_mask,
                                     np.ascontiguousarray(e))
    return rows[:, :2].copy(), rows[:, 2:].copy(), support


# ----------------------------------------------------------------------------------------------
# The whole matcher


def sift_seeds(left_gray, right_gray, *, ratio=0.8, mutual=True, f_method="ransac",
               threshold_px=1.0, sift_params=None):
    """Verified SIFT matches for seeding, with timings.

    Returns a dict: ``x_left``, ``x_right`` (S, 2), ``F`` (or None), ``num_left``,
    ``num_right``, ``t_left``, ``t_right``, ``t_match``, ``note``.
    """
    det = make_detector("sift", **(sift_params or {}))
    t0 = time.perf_counter()
    fl = detect_and_describe(left_gray, "sift", detector=det)
    t1 = time.perf_counter()
    fr = detect_and_describe(right_gray, "sift", detector=det)
    t2 = time.perf_counter()
    il, ir = match_descriptors(fl.descriptors, fr.descriptors, ratio=ratio, mutual=mutual)
    xl, xr = fl.points[il], fr.points[ir]
    F, keep, note = verify_matches(xl, xr, f_method=f_method, threshold_px=threshold_px)
    t3 = time.perf_counter()
    return dict(x_left=xl[keep], x_right=xr[keep], F=F, num_left=len(fl), num_right=len(fr),
                t_left=t1 - t0, t_right=t2 - t1, t_match=t3 - t2, note=note)


def qdmatch(left_gray: np.ndarray, right_gray: np.ndarray, *, ratio: float = 0.8,
            mutual: bool = True, f_method: str = "ransac", threshold_px: float = 1.0,
            half_window: int = 2, radius: int = 1, eps: int = 1, zncc_min: float = 0.8,
            texture_min: float = 0.7, epipolar_band_px: float | None = 0.6,
            few_seeds: int = 100, few_seeds_band_px: float = 1.0,
            directional_texture: bool = True, reseed_rounds: int = 2,
            reseed_zncc_min: float = 0.9, reseed_margin: float = 0.1,
            cell_px: int = DISTRIBUTION_CELL_PX, model: str = "affine", resample_iters: int = 32,
            resample_tol_px: float = 1.0, min_support: int = 8, min_inlier_share: float = 0.8,
            min_spread_px: float = 1.0, thin_spread_px: float = 0.0, anchor: str = "centroid",
            interior_px: int = 3, interior_tol_px: float = 1.0, interior_shape: str = "line",
            aperture_max: float | None = 2.0, anchor_aperture_max: float | None = 1.0,
            sift_params: dict | None = None, keep_propagation: bool = False) -> MatchResult:
    """Quasi-dense matches of a grey pair (SIFT seeds -> propagation -> resampling).

    Args:
        left_gray, right_gray: uint8 (H, W) images of the same size.
        ratio, mutual, f_method, threshold_px: seed matching and verification; the
            final F check of the resampled matches uses ``f_method``/``threshold_px``.
        half_window, radius, eps, zncc_min, texture_min,
        directional_texture: propagation (see :func:`propagate`); the band and the
            directional texture use the seeds' F. ``texture_min`` is 0.7 grey levels
            per pixel (propagate's own default is 2): with the aperture and interior
            checks, weakly textured leaf and pot surfaces propagate without letting
            wrong matches through (Plants 23.6 -> 27 % of the cells, Middlebury mean
            95.5 -> 96.5 % correct).
        reseed_rounds, reseed_zncc_min, reseed_margin: extra propagation passes from
            epipolar-search seeds in unreached textured regions (see :func:`propagate`).
        epipolar_band_px: half-width (pixels) of the band around the seeds' epipolar
            lines that propagated matches must lie in. 0.6 px keeps the integer
            candidates of a nearly rectified pair to the row nearest the line: a band of
            1 px lets a slanted edge match one row off, pixels off in disparity.
        few_seeds, few_seeds_band_px: with fewer than ``few_seeds`` verified seeds the
            F is less certain and the band is widened to ``few_seeds_band_px``.
        aperture_max: propagation only through windows whose aperture coupling (see
            :func:`aperture_coupling`) is at most this (None: no limit); it keeps integer
            matches off edges nearly along the epipolar lines, where a fraction of a pixel
            of row offset becomes pixels of disparity error.
        cell_px, model, resample_iters, resample_tol_px, min_support,
        min_inlier_share, min_spread_px, thin_spread_px, anchor, interior_px,
        interior_tol_px, interior_shape: resampling (see :func:`resample`).
        anchor_aperture_max: a region's match is placed only on a pixel whose aperture
            coupling is at most this (None: anywhere).
        sift_params: arguments of ``cv2.SIFT_create``.
        keep_propagation: store the :class:`Propagation` in ``extras["propagation"]``.

    Returns:
        :class:`MatchResult` (method ``"qdmatch"``) whose matches are the resampled
        region centres; ``t_propagation``/``t_resample`` are timed separately and
        ``extras`` holds ``num_seeds`` and ``num_propagated``. Without seeds (no
        texture) the result is empty and ``note`` says why.
    """
    size = (left_gray.shape[1], left_gray.shape[0])
    seeds = sift_seeds(left_gray, right_gray, ratio=ratio, mutual=mutual, f_method=f_method,
                       threshold_px=threshold_px, sift_params=sift_params)
    common = dict(method="qdmatch", image_size=size, num_left=seeds["num_left"],
                  num_right=seeds["num_right"], t_left=seeds["t_left"],
                  t_right=seeds["t_right"], t_match=seeds["t_match"])
    if len(seeds["x_left"]) == 0:
        why = seeds["note"] or "no verified SIFT matches"
        if seeds["num_left"] == 0 or seeds["num_right"] == 0:
            why = (f"SIFT found {seeds['num_left']} keypoints in the left and "
                   f"{seeds['num_right']} in the right image")
        return MatchResult(x_left=np.zeros((0, 2)), x_right=np.zeros((0, 2)),
                           note=f"no seeds for propagation ({why}; image without texture?)",
                           extras={"num_seeds": 0, "num_propagated": 0}, **common)
    t0 = time.perf_counter()
    F_prop = seeds["F"]
    band = epipolar_band_px
    if band is not None and len(seeds["x_left"]) < few_seeds:
        band = max(band, few_seeds_band_px)
    prop = propagate(left_gray, right_gray, seeds["x_left"], seeds["x_right"],
                     half_window=half_window, radius=radius, eps=eps, zncc_min=zncc_min,
                     texture_min=texture_min, F=F_prop, epipolar_band_px=band,
                     directional_texture=directional_texture, reseed_rounds=reseed_rounds,
                     reseed_zncc_min=reseed_zncc_min, reseed_margin=reseed_margin,
                     aperture_max=aperture_max)
    t1 = time.perf_counter()
    amask, e_l = None, None
    if F_prop is not None:
        e_l, _ = epipoles(np.asarray(F_prop, np.float64))
        if anchor_aperture_max is not None:
            amask = aperture_coupling(left_gray, half_window, e_l) <= anchor_aperture_max
    xl, xr, support = resample(prop, cell_px=cell_px, model=model, iters=resample_iters,
                               tol_px=resample_tol_px, min_support=min_support,
                               min_inlier_share=min_inlier_share, min_spread_px=min_spread_px,
                               thin_spread_px=thin_spread_px, anchor=anchor,
                               interior_px=interior_px, interior_tol_px=interior_tol_px,
                               interior_shape=interior_shape, anchor_mask=amask, epipole=e_l)
    F, note = seeds["F"], ""
    if len(xl) >= MIN_MATCHES_F:
        try:
            F, keep = estimate_fundamental(xl, xr, method=f_method, threshold_px=threshold_px)
            xl, xr, support = xl[keep], xr[keep], support[keep]
        except MatchingError as exc:
            note = f"resampled matches failed the F check: {exc}"
            xl, xr, support = xl[:0], xr[:0], support[:0]
    else:
        note = f"only {len(xl)} regions could be resampled"
    t2 = time.perf_counter()
    extras = {"num_seeds": prop.num_seeds, "num_propagated": len(prop), "support": support}
    if keep_propagation:
        extras["propagation"] = prop
    return MatchResult(x_left=xl, x_right=xr, F=F, note=note, t_propagation=t1 - t0,
                       t_resample=t2 - t1, extras=extras, **common)
