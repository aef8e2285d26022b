"""Resampling of propagated matches (Lhuillier & Quan, step 3): one match per region whose
local affine map (or homography), fitted by RANSAC, explains its matches."""
from __future__ import annotations

import numpy as np
from numba import njit

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.quasi_dense.propagation import Propagation
from canopy_stereo.features.result import DISTRIBUTION_CELL_PX

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
