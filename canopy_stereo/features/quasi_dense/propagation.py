"""Best-first propagation of quasi-dense matches from seeds (Lhuillier & Quan, step 2), and
reseeding by epipolar search in regions growth does not reach (step 2b).

A priority queue (a numba heap) of accepted matches keyed by their ZNCC; the kernel is single
threaded (the propagation is inherently sequential) and caches each left pixel's candidate
ZNCCs for the last displacement it was reached with.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.quasi_dense.windows import (
    _zncc,
    aperture_coupling,
    epipoles,
    window_statistics,
    zncc_at,
)

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
