"""ELAS stage 6: dense maximum-a-posteriori matching.

For every pixel inside the support-point hull (and with descriptor texture at
least ``match_texture``, and more than 2 pixels from the left/right border) the
plane of its triangle predicts ``mu = int(a*u + b*v + c)`` (truncated, as the
original; rounding instead raised bad>2 by up to 1.8 points on Middlebury 2014).
The candidates are

* the disparities of the pixel's grid cell, at cost ``SAD``,
* every ``d`` in ``[mu - r, mu + r]``, at cost ``SAD + P[|d - mu|]`` when the plane
  is valid (plain ``SAD`` otherwise),

where SAD is the absolute difference of the two 16-byte descriptors and ``P`` is
the (negative) prior of :func:`prior_table`. The lowest cost wins (ties: the first
candidate evaluated: grid candidates outside the window first, then the window,
each in increasing ``d``). The matched pixel of ``(u, v)`` is ``(u - d, v)`` in the right
image when
matching the left one and ``(u + d, v)`` when matching the right one; it must also
be more than 2 pixels from the border.

Each cost is one vector instruction (:func:`~canopy_stereo.elas.simd.sad16`);
four neighbouring pixels of one grid cell are matched together
(:func:`~canopy_stereo.elas.simd.quad_first_min`): one 64-byte SAD per candidate
(their descriptors, and those of their matches at any one ``d``, lie side by side),
each pixel's own window, prior and largest disparity applied per lane (so pixels with
different plane predictions, near the left/right border or not matched at all share
the group) and their first minima kept in one vector; with AVX-512 twenty, sixteen or
eight pixels (:func:`~canopy_stereo.elas.simd.penta_first_min` and its kin: a 20-pixel
cell row in one call); with subsampling (any x86 CPU) the ten matched pixels of a cell
row on two matched rows (:func:`~canopy_stereo.elas.simd.penta_first_min_spread2_two_rows`);
rows run in parallel.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from canopy_stereo.elas.grid import candidate_ranks
from canopy_stereo.elas.parallel import run_row_bands
from canopy_stereo.elas.simd import (
    DESC_BYTES,
    GROUP_LANES,
    PRIOR_REGISTER,
    PRIOR_REGISTER_WIDE,
    PSADBW_WIDTH,
    hexa_first_min,
    octo_first_min,
    penta_first_min,
    penta_first_min_spread2_two_rows,
    quad_first_min,
    sad16,
)
from canopy_stereo.errors import CanopyStereoError

#: Pixels closer than this to the left/right border are not matched.
MATCH_BORDER = 2
#: Marks "no candidate yet" in the cost accumulators.
_NO_COST = np.int32(2147483647)
#: Twenty, sixteen or eight pixels per call (:func:`~canopy_stereo.elas.simd.penta_first_min`,
#: :func:`~canopy_stereo.elas.simd.hexa_first_min`,
#: :func:`~canopy_stereo.elas.simd.octo_first_min`) where the CPU has 64-byte ``psadbw``
#: (AVX-512BW); else four (each 64-byte SAD would cost two or four instructions, and the
#: prior would not fit in a register).
_GROUPS = PSADBW_WIDTH == 64
#: Subsampled matching twenty pixels per call (:func:`_match_row_pairs`) on every x86 CPU: one
#: pixel at a time took 30-40 % longer also with 16- and 32-byte ``psadbw`` (1280x720 Plants,
#: numba targeting haswell); elsewhere (portable IR, not measured) one pixel at a time.
_SPREAD_GROUPS = PSADBW_WIDTH >= 16
#: Narrowest image matched by the subsampled group path (:func:`_match_row_pairs`): ten pixels
#: every second column, and their matches, are read up to forty columns beyond their row (rows
#: 1 .. H-2 only: the neighbouring rows hold them).
_SPREAD_MIN_WIDTH = 64


def prior_table(beta: float, gamma: float, sigma: float, size: int) -> np.ndarray:
    """int32 (size,) prior ``P[D] = int((ln gamma - ln(gamma + exp(-D^2 / (2 sigma^2)))) / beta)``.

    Non-positive: a bonus for disparities close to the plane's prediction.
    """
    delta = np.arange(size, dtype=np.float64)
    val = (math.log(gamma) - np.log(gamma + np.exp(-delta ** 2 / (2.0 * sigma ** 2)))) / beta
    return np.trunc(val).astype(np.int32)


def window_prior(prior: np.ndarray, radius: int) -> np.ndarray:
    """int32 (max(2 radius + 1, PRIOR_REGISTER, PRIOR_REGISTER_WIDE),) the prior across the
    plane window: entry ``i`` is ``prior[|i - radius|]`` (disparity ``mu - radius + i``),
    zeros after ``2 radius`` (:func:`~canopy_stereo.elas.simd.quad_first_min` and
    :func:`~canopy_stereo.elas.simd.octo_first_min` may load them)."""
    offsets = np.abs(np.arange(2 * radius + 1) - radius)
    out = np.zeros(max(2 * radius + 1, PRIOR_REGISTER, PRIOR_REGISTER_WIDE), np.int32)
    out[:2 * radius + 1] = np.asarray(prior, np.int32)[offsets]
    return out


def plane_radius(sigma: float, sradius: float) -> int:
    """Half-width of the plane window: ``max(ceil(sigma * sradius), 2)`` disparities."""
    return max(int(math.ceil(sigma * sradius)), 2)


@njit(cache=True, inline="always")
def _candidate_runs(flat_ranks, ranks, n_ranks, disp_min, hi_max, mu_lo, mu_hi, radius):  # pragma: no cover
    # the grid candidates in [disp_min, hi_max] below and above the window every pixel of a
    # group shares, [mu_hi - radius, mu_lo + radius]: (first, below, above, stop) positions in
    # the cell's increasing candidate list, the runs [first, below) and [above, stop)
    first = np.int64(flat_ranks[ranks + min(disp_min, n_ranks - 1)])
    stop = np.int64(flat_ranks[ranks + min(hi_max + 1, n_ranks - 1)])
    below = np.int64(flat_ranks[ranks + min(max(mu_hi - radius, 0), n_ranks - 1)])
    above = np.int64(flat_ranks[ranks + min(max(mu_lo + radius + 1, 0), n_ranks - 1)])
    below = min(max(below, first), stop)
    above = min(max(above, below), stop)
    return first, below, above, stop


@njit(cache=True, inline="always")
def _flat_views(desc_own, desc_other, grid_lists, grid_ranks):
    """The descriptors (uint8 (H, W, 16)) and the grid's candidate lists and ranks (int32
    (gh, gw, n)) as 1-D views: positions are offsets into them (a view per cell or pixel
    would cost reference counting)."""
    return desc_own.reshape(-1), desc_other.reshape(-1), grid_lists.reshape(-1), \
        grid_ranks.reshape(-1)


@njit(cache=True, inline="always")
def _subpixel_offset(flat_own, flat_other, a, sign, best_d, d_lo, d_hi, off_row, c):
    """Parabola refinement of output column ``c`` (descriptor at byte ``a``, winner
    ``best_d``), written to ``off_row[c]`` only where the winner is also a local minimum
    of the cost itself (then the vertex lies within half a pixel)."""
    if best_d - 1 >= d_lo and best_d + 1 <= d_hi:
        b = a - sign * best_d * DESC_BYTES
        c0 = sad16(flat_own, a, flat_other, b)
        cm = sad16(flat_own, a, flat_other, b + sign * DESC_BYTES)
        cp = sad16(flat_own, a, flat_other, b - sign * DESC_BYTES)
        if c0 <= cm and c0 <= cp and cm + cp > 2 * c0:
            off_row[c] = np.float32(0.5 * (cm - cp) / (cm + cp - 2 * c0))


@njit(cache=True, nogil=True)
def _match_rows(desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists,
                grid_counts, grid_ranks, grid_size, prior, prior_window, radius, sign, disp_min,
                disp_max, match_texture, step, subpixel, cells, out, offsets, row_start, row_stop):
    """Output rows ``[row_start, row_stop)`` of :func:`match_job` (arguments there).

    With ``step`` 1, four (with AVX-512 up to twenty) neighbouring pixels of one grid
    cell are matched together (:func:`~canopy_stereo.elas.simd.quad_first_min` and the
    wider intrinsics): each candidate's costs are descriptors side by side in both
    images, and each pixel keeps its own first minimum exactly as when matched alone.
    With ``step`` 2 one pixel at a time (on x86 :func:`_match_row_pairs` takes all but
    the first and last rows).
    (Written out in one function: helpers taking arrays cost reference counting per call.)
    """
    h, w, _ = desc_own.shape
    flat_own, flat_other, flat_lists, flat_ranks = _flat_views(desc_own, desc_other, grid_lists,
                                                               grid_ranks)
    n_disp = grid_lists.shape[2]
    n_ranks = grid_ranks.shape[2]
    lane_best = np.empty(4, np.int64)
    lane_hi = np.empty(4, np.int64)
    lanes = np.empty(3 * GROUP_LANES, np.int32)    # a group's mu, largest d, prior flag
    lane_out = np.empty(GROUP_LANES, np.int32)
    # matched columns x = u - sign*d must satisfy MATCH_BORDER <= x < w - MATCH_BORDER
    n_cells = grid_counts.shape[1]
    for r in range(row_start, row_stop):
        v = r * step
        gy = v // grid_size
        row = v * w * DESC_BYTES
        tri_row = tri_map[v]
        tex_row = tex_own[v]
        out_row = out[r]
        off_row = offsets[r]
        cells_row = cells[gy]
        for gx in range(n_cells):
            if cells_row[gx] == 0:
                continue                            # a cell not to match: left invalid
            cell = (gy * n_cells + gx) * n_disp     # the cell's candidates start here
            n_grid = grid_counts[gy, gx]
            # its candidates below d: flat_ranks[ranks + clip(d, 0, n_ranks - 1)]
            ranks = (gy * n_cells + gx) * n_ranks
            u_first = max(gx * grid_size, MATCH_BORDER)
            u_first = ((u_first + step - 1) // step) * step
            u_stop = min((gx + 1) * grid_size, w - MATCH_BORDER)
            u = u_first
            while u < u_stop:
                # ---- twenty, sixteen or eight pixels u .. u+n-1 at once (AVX-512): as the four
                # below, with the pixels' predictions, largest disparities and prior flags in
                # `lanes` (rows of GROUP_LANES entries)
                if _GROUPS and step == 1 and u + 8 <= u_stop and v >= 1 and v < h - 1:
                    n = 20 if u + 20 <= u_stop else (16 if u + 16 <= u_stop else 8)
                    n_on = 0
                    mu_lo = 2147483647
                    mu_hi = -2147483648
                    hi_max = -1
                    for k in range(n):
                        t = tri_row[u + k]
                        if t >= 0 and tex_row[u + k] >= match_texture:
                            mu_k = int(planes[t, 0] * (u + k) + planes[t, 1] * v + planes[t, 2])
                            n_on += 1
                            mu_lo = min(mu_lo, mu_k)
                            mu_hi = max(mu_hi, mu_k)
                            hi_k = min(disp_max, u + k - MATCH_BORDER) if sign > 0 else \
                                min(disp_max, w - MATCH_BORDER - 1 - u - k)
                            hi_max = max(hi_max, hi_k)
                            lanes[k] = mu_k
                            lanes[GROUP_LANES + k] = hi_k
                            lanes[2 * GROUP_LANES + k] = plane_valid[t]
                        else:
                            lanes[GROUP_LANES + k] = -1
                            lanes[2 * GROUP_LANES + k] = 0
                    if n_on == 0:
                        u += n          # none of them is matched
                        continue
                    if n_on < n:
                        # a pixel that is not matched takes a prediction of the others
                        # (within [mu_lo, mu_hi]: the union of windows stays as small)
                        for k in range(n):
                            if lanes[GROUP_LANES + k] < 0:
                                lanes[k] = mu_lo
                    first, below, above, stop = _candidate_runs(flat_ranks, ranks, n_ranks, disp_min, hi_max,
                                                                mu_lo, mu_hi, radius)
                    a0 = row + u * DESC_BYTES
                    w_lo = max(mu_lo - radius, disp_min)
                    w_hi = min(mu_hi + radius, hi_max)
                    if n == 20:
                        penta_first_min(flat_own, a0, flat_other, a0, -sign * DESC_BYTES,
                                        flat_lists, cell + first, cell + below, cell + above,
                                        cell + stop, w_lo, w_hi, radius, prior_window, lanes,
                                        lane_out)
                    elif n == 16:
                        hexa_first_min(flat_own, a0, flat_other, a0, -sign * DESC_BYTES,
                                       flat_lists, cell + first, cell + below, cell + above,
                                       cell + stop, w_lo, w_hi, radius, prior_window, lanes,
                                       lane_out)
                    else:
                        octo_first_min(flat_own, a0, flat_other, a0, -sign * DESC_BYTES,
                                       flat_lists, cell + first, cell + below, cell + above,
                                       cell + stop, w_lo, w_hi, radius, prior_window, lanes,
                                       lane_out)
                    for k in range(n):
                        best_d = lane_out[k]
                        if best_d >= 0:
                            out_row[u + k] = np.float32(best_d)
                            if subpixel:
                                _subpixel_offset(flat_own, flat_other, row + (u + k) * DESC_BYTES,
                                                 sign, best_d, disp_min, lanes[GROUP_LANES + k],
                                                 off_row, u + k)
                    u += n
                    continue
                # ---- four pixels u .. u+3 at once: every candidate of any of the four is
                # one 64-byte SAD, each pixel's own candidates unmasked (its window, prior
                # and largest disparity; a pixel that is not matched has every candidate
                # masked). Rows 1 .. h-2 only: there the 64-byte loads of a lane beyond its
                # bounds stay inside the descriptor array (one column off at most).
                if step == 1 and u + 4 <= u_stop and v >= 1 and v < h - 1:
                    t0 = tri_row[u]
                    t1 = tri_row[u + 1]
                    t2 = tri_row[u + 2]
                    t3 = tri_row[u + 3]
                    on0 = (t0 >= 0) & (tex_row[u] >= match_texture)
                    on1 = (t1 >= 0) & (tex_row[u + 1] >= match_texture)
                    on2 = (t2 >= 0) & (tex_row[u + 2] >= match_texture)
                    on3 = (t3 >= 0) & (tex_row[u + 3] >= match_texture)
                    if not (on0 | on1 | on2 | on3):
                        u += 4          # none of the four is matched
                        continue
                    # each pixel's largest disparity (its matched column inside the border),
                    # -1 when it is not matched; the smallest is disp_min for all four
                    # (MATCH_BORDER <= u and u + 3 < w - MATCH_BORDER)
                    if sign > 0:
                        hi0 = min(disp_max, u - MATCH_BORDER)
                        hi1 = min(disp_max, u + 1 - MATCH_BORDER)
                        hi2 = min(disp_max, u + 2 - MATCH_BORDER)
                        hi3 = min(disp_max, u + 3 - MATCH_BORDER)
                    else:
                        hi0 = min(disp_max, w - MATCH_BORDER - 1 - u)
                        hi1 = min(disp_max, w - MATCH_BORDER - 2 - u)
                        hi2 = min(disp_max, w - MATCH_BORDER - 3 - u)
                        hi3 = min(disp_max, w - MATCH_BORDER - 4 - u)
                    # truncated, as the original; a pixel that is not matched takes the
                    # prediction of one that is (it keeps the union of windows small)
                    mu0 = mu1 = mu2 = mu3 = 0
                    p0 = p1 = p2 = p3 = False
                    if on0:
                        mu0 = int(planes[t0, 0] * u + planes[t0, 1] * v + planes[t0, 2])
                        p0 = plane_valid[t0]
                    else:
                        hi0 = -1
                    if on1:
                        mu1 = int(planes[t1, 0] * (u + 1) + planes[t1, 1] * v + planes[t1, 2])
                        p1 = plane_valid[t1]
                    else:
                        hi1 = -1
                    if on2:
                        mu2 = int(planes[t2, 0] * (u + 2) + planes[t2, 1] * v + planes[t2, 2])
                        p2 = plane_valid[t2]
                    else:
                        hi2 = -1
                    if on3:
                        mu3 = int(planes[t3, 0] * (u + 3) + planes[t3, 1] * v + planes[t3, 2])
                        p3 = plane_valid[t3]
                    else:
                        hi3 = -1
                    if not (on0 & on1 & on2 & on3):
                        mu_on = mu0 if on0 else (mu1 if on1 else (mu2 if on2 else mu3))
                        mu0 = mu0 if on0 else mu_on
                        mu1 = mu1 if on1 else mu_on
                        mu2 = mu2 if on2 else mu_on
                        mu3 = mu3 if on3 else mu_on
                    hi_max = max(max(hi0, hi1), max(hi2, hi3))
                    mu_lo = min(min(mu0, mu1), min(mu2, mu3))
                    mu_hi = max(max(mu0, mu1), max(mu2, mu3))
                    # the grid candidates in [disp_min, hi_max] below and above the window
                    # every pixel shares, [mu_hi - r, mu_lo + r] (masked for all four, so
                    # not evaluated): two runs of the increasing cell list
                    first, below, above, stop = _candidate_runs(flat_ranks, ranks, n_ranks, disp_min, hi_max,
                                                                mu_lo, mu_hi, radius)
                    a0 = row + u * DESC_BYTES
                    best0, best1, best2, best3 = quad_first_min(
                        flat_own, a0, flat_other, a0, -sign * DESC_BYTES, flat_lists,
                        cell + first, cell + below, cell + above, cell + stop,
                        max(mu_lo - radius, disp_min), min(mu_hi + radius, hi_max),
                        radius, prior_window, mu0, mu1, mu2, mu3, hi0, hi1, hi2, hi3, p0, p1, p2,
                        p3)
                    lane_best[0] = best0
                    lane_best[1] = best1
                    lane_best[2] = best2
                    lane_best[3] = best3
                    lane_hi[0] = hi0
                    lane_hi[1] = hi1
                    lane_hi[2] = hi2
                    lane_hi[3] = hi3
                    for k in range(4):
                        best_d = lane_best[k]
                        if best_d >= 0:
                            out_row[u + k] = np.float32(best_d)
                            if subpixel:
                                _subpixel_offset(flat_own, flat_other, row + (u + k) * DESC_BYTES,
                                                 sign, best_d, disp_min, lane_hi[k], off_row,
                                                 u + k)
                    u += 4
                    continue
                # ---- one pixel at a time (the definition; the four-pixel path agrees with
                # it): the last pixels of a cell (fewer than four), rows 0 and h - 1, step 2
                stop = min(u + 4, u_stop) if step == 1 else u + step
                for uu in range(u, stop, step):
                    t = tri_row[uu]
                    if t < 0 or tex_row[uu] < match_texture:
                        continue
                    if sign > 0:
                        d_lo = max(disp_min, uu - (w - MATCH_BORDER - 1))
                        d_hi = min(disp_max, uu - MATCH_BORDER)
                    else:
                        d_lo = max(disp_min, MATCH_BORDER - uu)
                        d_hi = min(disp_max, w - MATCH_BORDER - 1 - uu)
                    # truncated, as the original
                    mu = int(planes[t, 0] * uu + planes[t, 1] * v + planes[t, 2])
                    w_lo = mu - radius
                    w_hi = mu + radius
                    a = row + uu * DESC_BYTES
                    best_e = _NO_COST
                    best_d = -1
                    for j in range(n_grid):
                        d = flat_lists[cell + j]
                        if (d >= w_lo and d <= w_hi) or d < d_lo or d > d_hi:
                            continue
                        e = sad16(flat_own, a, flat_other, a - sign * d * DESC_BYTES)
                        if e < best_e:
                            best_e = e
                            best_d = d
                    use_prior = plane_valid[t]
                    for d in range(max(w_lo, d_lo), min(w_hi, d_hi) + 1):
                        e = sad16(flat_own, a, flat_other, a - sign * d * DESC_BYTES)
                        if use_prior:
                            e += prior[abs(d - mu)]
                        if e < best_e:
                            best_e = e
                            best_d = d
                    if best_d < 0:
                        continue
                    c = uu // step
                    out_row[c] = np.float32(best_d)
                    if subpixel:
                        _subpixel_offset(flat_own, flat_other, a, sign, best_d, d_lo, d_hi,
                                         off_row, c)
                u = stop


@njit(cache=True, nogil=True)
def _match_row_pairs(desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists,
                     grid_counts, grid_ranks, grid_size, prior, prior_window, radius, sign,
                     disp_min, disp_max, match_texture, step, subpixel, cells, out, offsets,
                     row_start, row_stop):
    """:func:`_match_rows` with subsampling (``step`` 2) on x86: two matched rows of one
    grid cell row at once, ten pixels (every second column) of each in one twenty-lane call
    (:func:`~canopy_stereo.elas.simd.penta_first_min_spread2_two_rows`; a cell's candidates
    are the same on both rows). A row without a partner in its cell row or band takes the
    same call with the second row's lanes unmatched; the first and last rows and images
    narrower than :data:`_SPREAD_MIN_WIDTH` go through :func:`_match_rows` (one pixel at a
    time). Arguments and outputs as there: ``desc_*`` uint8 (H, W, 16), ``tex_own`` int32
    (H, W), ``tri_map`` int32 (H, W) (even rows read), ``out``/``offsets`` float32
    (ceil(H/2), ceil(W/2)) (offsets (ceil(H/2), 0) without ``subpixel``)."""
    h, w, _ = desc_own.shape
    flat_own, flat_other, flat_lists, flat_ranks = _flat_views(desc_own, desc_other, grid_lists,
                                                               grid_ranks)
    flat_tri = tri_map.reshape(-1)
    flat_tex = tex_own.reshape(-1)
    n_disp = grid_lists.shape[2]
    n_ranks = grid_ranks.shape[2]
    n_cells = grid_counts.shape[1]
    lanes = np.empty(3 * GROUP_LANES, np.int32)
    lane_out = np.empty(GROUP_LANES, np.int32)
    half = GROUP_LANES // 2                 # lanes per row
    row_bytes = 2 * w * DESC_BYTES          # from one matched row to the next
    r = row_start
    while r < row_stop:
        v = 2 * r
        if v < 1 or v >= h - 1 or w < _SPREAD_MIN_WIDTH:
            _match_rows(desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists,
                        grid_counts, grid_ranks, grid_size, prior, prior_window, radius, sign,
                        disp_min, disp_max, match_texture, step, subpixel, cells, out, offsets,
                        r, r + 1)
            r += 1
            continue
        # the next matched row too when it is in this band and cell row (and not the last)
        rows = 2 if r + 1 < row_stop and v + 2 < h - 1 and \
            v // grid_size == (v + 2) // grid_size else 1
        second_at = row_bytes if rows == 2 else 0   # (one row: its lanes read it again)
        gy = v // grid_size
        row = v * w * DESC_BYTES
        cells_row = cells[gy]
        for gx in range(n_cells):
            if cells_row[gx] == 0:
                continue
            cell = (gy * n_cells + gx) * n_disp
            ranks = (gy * n_cells + gx) * n_ranks
            u_first = max(gx * grid_size, MATCH_BORDER)
            u_first = ((u_first + 1) // 2) * 2
            u_stop = min((gx + 1) * grid_size, w - MATCH_BORDER)
            for u in range(u_first, u_stop, 2 * half):
                m = min((u_stop - u + 1) // 2, half)    # pixels u, u+2, .. of each row
                n_on = 0
                mu_lo = 2147483647
                mu_hi = -2147483648
                hi_max = -1
                for k in range(GROUP_LANES):
                    lanes[GROUP_LANES + k] = -1     # not matched unless set below
                    lanes[2 * GROUP_LANES + k] = 0
                for second in range(rows):
                    vk = v + 2 * second
                    at = vk * w + u                 # pixel (u, vk) in the flat maps
                    for j in range(m):
                        t = flat_tri[at + 2 * j]
                        if t < 0 or flat_tex[at + 2 * j] < match_texture:
                            continue
                        uk = u + 2 * j
                        k = second * half + j
                        mu_k = int(planes[t, 0] * uk + planes[t, 1] * vk + planes[t, 2])
                        n_on += 1
                        mu_lo = min(mu_lo, mu_k)
                        mu_hi = max(mu_hi, mu_k)
                        hi_k = min(disp_max, uk - MATCH_BORDER) if sign > 0 else \
                            min(disp_max, w - MATCH_BORDER - 1 - uk)
                        hi_max = max(hi_max, hi_k)
                        lanes[k] = mu_k
                        lanes[GROUP_LANES + k] = hi_k
                        lanes[2 * GROUP_LANES + k] = plane_valid[t]
                if n_on == 0:
                    continue
                for k in range(GROUP_LANES):
                    if lanes[GROUP_LANES + k] < 0:
                        lanes[k] = mu_lo    # (its window inside the others' union)
                first, below, above, stop = _candidate_runs(flat_ranks, ranks, n_ranks, disp_min,
                                                            hi_max, mu_lo, mu_hi, radius)
                a0 = row + u * DESC_BYTES
                penta_first_min_spread2_two_rows(
                    flat_own, a0, flat_other, a0, -sign * DESC_BYTES, flat_lists, cell + first,
                    cell + below, cell + above, cell + stop, max(mu_lo - radius, disp_min),
                    min(mu_hi + radius, hi_max), radius, prior_window, lanes, lane_out, second_at)
                c0 = u // 2
                for second in range(rows):
                    out_row = out[r + second]
                    for j in range(m):
                        k = second * half + j
                        best_d = lane_out[k]
                        if best_d >= 0:
                            out_row[c0 + j] = np.float32(best_d)
                            if subpixel:
                                _subpixel_offset(flat_own, flat_other,
                                                 row + second * row_bytes + (u + 2 * j) * DESC_BYTES,
                                                 sign, best_d, disp_min, lanes[GROUP_LANES + k],
                                                 offsets[r + second], c0 + j)
        r += rows


def match_job(desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists,
              grid_counts, grid_size, prior, radius, sign, disp_min, disp_max, match_texture,
              step, subpixel, *, cells=None, workspace=None):
    """Dense matching of one image as a row job for
    :func:`~canopy_stereo.elas.parallel.run_row_bands`: returns ``(job, disp, offset)``;
    the outputs are filled when the job has run.

    Args:
        desc_own, desc_other: uint8 (H, W, 16) descriptors.
        tex_own: int32 (H, W) descriptor texture of the own image.
        tri_map: int32 (H, W) triangle index per pixel (-1 outside the hull); only the
            rows ``0, step, 2 step, ..`` are read.
        planes: float32 (T, 3) plane ``(a, b, c)`` per triangle, own coordinates.
        plane_valid: bool (T,) whether the plane's prior applies.
        grid_lists, grid_counts: the disparity grid of the own image.
        grid_size: grid cell size in pixels.
        prior: int32 (>= radius+1,) prior table.
        radius: plane window half-width.
        sign: +1 matching the left image (other pixel ``u - d``), -1 the right (``u + d``).
        disp_min, disp_max: search range.
        match_texture: minimum texture of a matched pixel.
        step: 1, or 2 for subsampling (every second row and column).
        subpixel: compute the parabola refinement.
        cells: uint8 or bool (gh, gw), the shape of ``grid_counts``: grid cells to match
            (nonzero); the pixels of the other cells stay invalid (-1). None: every cell.
        workspace: a :class:`~canopy_stereo.elas.workspace.Workspace` to take the two
            output maps from (overwritten by its next use); fresh arrays when None.

    Returns:
        ``(disp, offset)``, both float32 (ceil(H/step), ceil(W/step)): ``disp`` holds
        integer disparities (-1 = none); ``offset`` the parabola refinement in
        [-0.5, 0.5] (0 where none or ``subpixel`` is off), kept apart so that the
        consistency check and the segment filter see the same integer map with and
        without refinement. With a ``workspace`` and ``subpixel`` off, ``offset`` is an
        empty (ceil(H/step), 0) array instead (no refinement: nothing to clear per frame).
    """
    h, w = tri_map.shape
    out_shape = ((h + step - 1) // step, (w + step - 1) // step)
    if workspace is None:
        disp = np.full(out_shape, -1.0, dtype=np.float32)
        offsets = np.zeros(out_shape, dtype=np.float32)
    else:
        disp = workspace.array("disp", out_shape, np.float32)
        disp.fill(-1.0)
        # without refinement the kernel never writes an offset: empty rows, nothing to clear
        offsets = workspace.array("offsets", out_shape if subpixel else (out_shape[0], 0), np.float32)
        if subpixel:
            offsets.fill(0.0)
    if cells is None:
        cells = np.ones(grid_counts.shape, np.uint8)
    cells = np.ascontiguousarray(np.asarray(cells) != 0).view(np.uint8)
    if cells.shape != grid_counts.shape:
        raise CanopyStereoError(f"the cells to match must have the disparity grid's shape "
                                f"{grid_counts.shape}, got {cells.shape}")
    ranks = candidate_ranks(grid_lists, grid_counts, workspace=workspace)
    args = (desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists, grid_counts,
            ranks, int(grid_size), prior, window_prior(prior, int(radius)), int(radius),
            int(sign), int(disp_min), int(disp_max), int(match_texture), int(step),
            bool(subpixel), cells, disp, offsets)
    kernel = _match_row_pairs if _SPREAD_GROUPS and step == 2 else _match_rows
    return (kernel, out_shape[0], args), disp, offsets


def dense_match(*args):
    """Dense disparity of one image: :func:`match_job` run at once; returns ``(disp, offset)``."""
    job, disp, offsets = match_job(*args)
    run_row_bands(job)
    return disp, offsets
