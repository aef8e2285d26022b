"""ELAS stage 7: post-processing of float32 disparity maps (invalid = negative).

All functions take and return float32 (H, W) maps; valid disparities are >= 0.
The maps may be subsampled (``step = 2``): disparities are then still in
full-resolution pixels while columns are ``u // step``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from canopy_stereo.elas.parallel import run_row_bands
from canopy_stereo.elas.simd import LR_LANES, MEAN_LANES, lr_keep8, step_mean16

INVALID = np.float32(-1.0)
#: Gap interpolation: ends closer than this are averaged, else the smaller one is used.
DISCONTINUITY_THRESHOLD = 3.0
#: Adaptive mean: taps at offsets -4..+3 along each axis.
MEAN_TAPS_BEFORE = 4
MEAN_TAPS_AFTER = 3
#: Median filter: taps at offsets -3..+3 along each axis.
MEDIAN_RADIUS = 3


@njit(cache=True, inline="always")
def _lr_keep(d, c2, row_other, threshold):
    """:data:`INVALID` if ``d`` is valid (>= 0) and its partner ``row_other[c2]`` is
    missing (``c2`` out of range, partner negative) or differs by more than
    ``threshold``; else ``d`` (branch-free)."""
    w = row_other.shape[0]
    outside = (c2 < 0) | (c2 >= w)
    partner = row_other[min(max(c2, 0), w - 1)]
    bad = outside | (partner < 0) | (abs(d - partner) > threshold)
    return INVALID if (d >= 0) & bad else d


@njit(cache=True, nogil=True)
def _lr_check(d_left, d_right, threshold, step, want_right, out_l, out_r, row_start, row_stop):
    """Rows ``[row_start, row_stop)`` of the checked maps (H, W) float32, written to
    ``out_l`` and, with ``want_right``, ``out_r``."""
    w = d_left.shape[1]
    inv_step = 1.0 / step
    vector_stop = w - w % LR_LANES
    for v in range(row_start, row_stop):
        row_l = d_left[v]
        row_r = d_right[v]
        dst_l = out_l[v]
        for c in range(0, vector_stop, LR_LANES):
            lr_keep8(row_l, c, row_r, step, inv_step, -1.0, threshold, dst_l)
        for c in range(vector_stop, w):
            d = row_l[c]
            # partner column round((c*step - d) / step), rounding half up
            x = (c * step - d) * inv_step + 0.5
            c2 = int(x) if x >= 0 else -1
            dst_l[c] = _lr_keep(d, c2, row_r, threshold)
        if want_right:
            dst_r = out_r[v]
            for c in range(0, vector_stop, LR_LANES):
                lr_keep8(row_r, c, row_l, step, inv_step, 1.0, threshold, dst_r)
            for c in range(vector_stop, w):
                d = row_r[c]
                x = (c * step + d) * inv_step + 0.5
                c1 = int(x) if x >= 0 else -1
                dst_r[c] = _lr_keep(d, c1, row_l, threshold)


def left_right_check(d_left: np.ndarray, d_right: np.ndarray, threshold: float,
                     *, step: int = 1, want_right: bool = True, workspace=None):
    """Invalidate pixels whose match in the other map disagrees by more than ``threshold``.

    Left pixel ``u`` with disparity ``d`` is checked against the right map at
    ``round(u - d)``, right pixel ``u`` against the left map at ``round(u + d)``
    (columns in full-resolution pixels, ``step`` for subsampled maps).
    Returns new maps ``(left, right)`` float32 (H, W); the inputs are not changed.
    ``want_right=False`` skips the right map's check and returns ``(left, None)``.
    With a :class:`~canopy_stereo.elas.workspace.Workspace` the left map is the
    workspace's (overwritten by its next use); the right one is always fresh.
    """
    d_left = np.ascontiguousarray(d_left, np.float32)
    out_l = np.empty_like(d_left) if workspace is None else \
        workspace.array("lr_left", d_left.shape, np.float32)
    d_right = np.ascontiguousarray(d_right, np.float32)
    out_r = np.empty_like(d_right) if want_right else d_right
    run_row_bands((_lr_check, d_left.shape[0], (d_left, d_right, float(threshold), int(step),
                                                bool(want_right), out_l, out_r)))
    return out_l, (out_r if want_right else None)


@njit(cache=True, nogil=True)
def _partner_cells(d_left, step, grid_size, width, cells):
    """Mark in ``cells`` (uint8 (gh, gw), zeroed by the caller) the grid cell of every right
    pixel the left-right check reads for ``d_left`` (:func:`_lr_check`'s partner column)."""
    rows, w = d_left.shape
    inv_step = 1.0 / step
    for r in range(rows):
        row = d_left[r]
        cell_row = cells[(r * step) // grid_size]
        for c in range(w):
            d = row[c]
            if d >= 0:
                x = (c * step - d) * inv_step + 0.5
                c2 = int(x) if x >= 0 else -1
                if 0 <= c2 < w and c2 * step < width:
                    cell_row[(c2 * step) // grid_size] = 1


def partner_cells(d_left: np.ndarray, *, step: int, grid_size: int, image_size: tuple[int, int]) -> np.ndarray:
    """uint8 (ceil(H / grid_size), ceil(W / grid_size)): 1 for the grid cells of the right
    image that hold a pixel :func:`left_right_check` reads for the left map ``d_left``
    (float32, rows/columns ``step`` pixels apart; ``image_size`` ``(W, H)`` full-resolution
    pixels). Only these cells of the right map decide the checked left map."""
    w, h = (int(v) for v in image_size)
    cells = np.zeros((-(-h // grid_size), -(-w // grid_size)), np.uint8)
    _partner_cells(np.ascontiguousarray(d_left, np.float32), int(step), int(grid_size), w, cells)
    return cells


@njit(cache=True, inline="always")
def _find_root(parent, r):
    """Root of ``r`` in the union-find forest ``parent``, halving the path on the way."""
    while parent[r] != r:
        parent[r] = parent[parent[r]]
        r = parent[r]
    return r


@njit(cache=True, inline="always")
def _unite(parent, a, b):
    """Join the trees of runs ``a`` and ``b`` (the smaller root becomes the root)."""
    x = _find_root(parent, a)
    y = _find_root(parent, b)
    if x < y:
        parent[y] = x
    elif y < x:
        parent[x] = y


@njit(cache=True, nogil=True)
def _segment_band(disp, sim_threshold, label, parent, run_size, run_start, band_end, out,
                  row_start, row_stop):
    """Rows ``[row_start, row_stop)`` of :func:`_remove_small_segments`: their row runs,
    numbered from ``row_start * W`` (a band never has more runs than pixels, so bands
    number apart), united through the vertical joins inside the band; the rows copied to
    ``out``; ``band_end[row_start]`` = one past the band's last run. ``label`` is written
    for valid pixels only (the joins read it only there).

    Two neighbouring pixels are joined when both are valid (>= 0) and differ by at most
    ``sim_threshold`` (a symmetric relation, so the segments are those of a flood fill).
    A row run is a maximal horizontally joined stretch (consecutive joins between the same
    two runs are united once). A NaN pixel joins nothing: a segment of its own, as in a
    flood fill seeded there.
    """
    h, w = disp.shape
    n_runs = row_start * w
    for v in range(row_start, row_stop):
        row = disp[v]
        lab = label[v]
        dst = out[v]
        for u in range(w):      # (a loop of its own: it vectorises)
            dst[u] = row[u]
        last_above = -1
        last_here = -1
        r = -1
        size = 0                # of run r, stored when it ends
        prev = np.float32(-1.0)
        for u in range(w):
            d = row[u]
            if d < 0:           # (the label of an invalid pixel is never read)
                prev = d
                continue
            # a new run unless joined to the left (branch-free test)
            join = (prev >= 0) & (abs(prev - d) <= sim_threshold)
            prev = d
            if not join:
                if r >= 0:
                    run_size[r] = size
                r = n_runs
                n_runs += 1
                parent[r] = r
                size = 0
                run_start[r] = v * w + u
            size += 1
            lab[u] = r
            if v > row_start:
                above = disp[v - 1, u]
                if (above >= 0) & (abs(above - d) <= sim_threshold):
                    ra = label[v - 1, u]
                    if ra != last_above or r != last_here:
                        last_above = ra
                        last_here = r
                        _unite(parent, ra, r)
        if r >= 0:
            run_size[r] = size
    band_end[row_start] = n_runs


@njit(cache=True, nogil=True)
def _join_bands(disp, sim_threshold, min_size, label, parent, run_size, run_length, band_end):
    """The serial middle of :func:`_remove_small_segments`: the vertical joins across band
    edges (a band starts at each row ``v`` with ``band_end[v] >= 0``), each segment's size
    at its root, then ``run_length[r]`` = the run's length if its segment is smaller than
    ``min_size``, else 0 (nothing to invalidate)."""
    h, w = disp.shape
    for v in range(1, h):
        if band_end[v] < 0:
            continue
        last_above = -1
        last_here = -1
        for u in range(w):
            d = disp[v, u]
            above = disp[v - 1, u]
            if (d >= 0) & (above >= 0) & (abs(above - d) <= sim_threshold):
                ra = label[v - 1, u]
                r = label[v, u]
                if ra != last_above or r != last_here:
                    last_above = ra
                    last_here = r
                    _unite(parent, ra, r)
    # segment sizes at the roots (each run's own length kept apart)
    for v in range(h):
        for r in range(v * w, band_end[v]):
            run_length[r] = run_size[r]
    for v in range(h):
        for r in range(v * w, band_end[v]):
            if parent[r] != r:
                run_size[_find_root(parent, r)] += run_size[r]
    for v in range(h):
        for r in range(v * w, band_end[v]):
            if run_size[_find_root(parent, r)] >= min_size:
                run_length[r] = 0


@njit(cache=True, nogil=True)
def _invalidate_runs(run_start, run_length, band_end, out, row_start, row_stop):
    """Rows ``[row_start, row_stop)`` (one band of :func:`_segment_band`): the pixels of the
    band's runs with a nonzero ``run_length`` invalidated (no per-pixel lookup)."""
    flat = out.reshape(-1)
    w = out.shape[1]
    for r in range(row_start * w, band_end[row_start]):
        start = run_start[r]
        for i in range(start, start + run_length[r]):
            flat[i] = INVALID


def _remove_small_segments(disp, sim_threshold, min_size, label, parent, run_size, run_start,
                           run_length, band_end, out):
    """Connected segments of row runs with union-find, then the runs of small segments
    invalidated in a copy of the map (``out``, returned).

    Row bands (:func:`~canopy_stereo.elas.parallel.run_row_bands`) find their runs and
    unite them inside the band (:func:`_segment_band`); one serial pass unites across the
    band edges and sizes the segments (:func:`_join_bands`); the bands then invalidate
    their small segments' runs (:func:`_invalidate_runs`). Segments, and so the output,
    do not depend on the bands. ``label`` int32 (H, W), ``parent``, ``run_size``,
    ``run_start`` and ``run_length`` int32 (H*W,), ``band_end`` int32 (H,) are scratch.
    """
    h = disp.shape[0]
    band_end[:] = -1
    run_row_bands((_segment_band, h, (disp, sim_threshold, label, parent, run_size, run_start,
                                      band_end, out)))
    _join_bands(disp, sim_threshold, min_size, label, parent, run_size, run_length, band_end)
    run_row_bands((_invalidate_runs, h, (run_start, run_length, band_end, out)))
    return out


def remove_small_segments(disp: np.ndarray, sim_threshold: float, min_size: int,
                          *, workspace=None) -> np.ndarray:
    """Invalidate 4-connected segments smaller than ``min_size`` pixels.

    Neighbouring valid pixels belong to one segment when their disparities differ
    by at most ``sim_threshold`` (chained, so a segment may drift slowly).
    Returns a new float32 (H, W) map, or with a
    :class:`~canopy_stereo.elas.workspace.Workspace` the workspace's map (overwritten
    by its next use) and scratch from it.
    """
    disp = np.ascontiguousarray(disp, np.float32)
    h, w = disp.shape
    if workspace is None:
        scratch = (np.empty((h, w), np.int32), np.empty(h * w, np.int32),
                   np.empty(h * w, np.int32), np.empty(h * w, np.int32),
                   np.empty(h * w, np.int32), np.empty(h, np.int32), np.empty_like(disp))
    else:
        scratch = (workspace.array("segments_label", (h, w), np.int32),
                   workspace.array("segments_parent", (h * w,), np.int32),
                   workspace.array("segments_run_size", (h * w,), np.int32),
                   workspace.array("segments_run_start", (h * w,), np.int32),
                   workspace.array("segments_run_length", (h * w,), np.int32),
                   workspace.array("segments_band_end", (h,), np.int32),
                   workspace.array("segments", (h, w), np.float32))
    return _remove_small_segments(disp, float(sim_threshold), int(min_size), *scratch)


@njit(cache=True, nogil=True)
def _fill_line(line, max_gap, discon, extrapolate):
    n = line.shape[0]
    count = 0
    for i in range(n):
        valid = line[i] >= 0
        if valid and count >= 1 and count <= max_gap and i - count > 0:
            fill = _gap_fill(line[i - count - 1], line[i], discon)
            for j in range(i - count, i):
                line[j] = fill
        count = 0 if valid else count + 1
    if extrapolate:
        for i in range(n):
            if line[i] >= 0:
                for j in range(max(i - max_gap, 0), i):
                    line[j] = line[i]
                break
        for i in range(n - 1, -1, -1):
            if line[i] >= 0:
                for j in range(i + 1, min(i + 1 + max_gap, n)):
                    line[j] = line[i]
                break


@njit(cache=True, inline="always")
def _gap_fill(d1, d2, discon):
    """Value of a gap between valid ends ``d1`` and ``d2`` (float32)."""
    if abs(d1 - d2) < discon:
        return np.float32(0.5 * (d1 + d2))
    return min(d1, d2)


@njit(cache=True, nogil=True)
def _fill_columns(out, max_gap, discon, extrapolate, col_start, col_stop):
    """:func:`_fill_line` on columns ``[col_start, col_stop)`` of ``out`` (H, W) in place,
    scanning rows (contiguous) with one run counter per column instead of transposing the
    map. Per row, one branch-free (vectorised) pass finds the columns whose gap ends there
    and updates the counters; the few gaps are filled after it (a fill writes only rows
    above)."""
    h = out.shape[0]
    w = col_stop - col_start
    count = np.zeros(w, dtype=np.int32)
    gap = np.zeros(w, dtype=np.int32)
    for i in range(h):
        row = out[i, col_start:col_stop]
        # which columns end a fillable gap here (its length in `gap`), the run counters
        ends = 0
        for u in range(w):
            n = count[u]
            valid = row[u] >= 0
            end = valid & (n >= 1) & (n <= max_gap) & (i - n > 0)
            gap[u] = n if end else 0
            ends += end
            count[u] = 0 if valid else n + 1
        if ends == 0:
            continue
        for u in range(w):
            n = gap[u]
            if n:
                c = col_start + u
                fill = _gap_fill(out[i - n - 1, c], row[u], discon)
                for j in range(i - n, i):
                    out[j, c] = fill
    if extrapolate:
        for u in range(col_start, col_stop):
            for i in range(h):
                if out[i, u] >= 0:
                    for j in range(max(i - max_gap, 0), i):
                        out[j, u] = out[i, u]
                    break
            for i in range(h - 1, -1, -1):
                if out[i, u] >= 0:
                    for j in range(i + 1, min(i + 1 + max_gap, h)):
                        out[j, u] = out[i, u]
                    break


@njit(cache=True, nogil=True)
def _fill_rows(disp, max_gap, discon, extrapolate, out, row_start, row_stop):
    """Rows ``[row_start, row_stop)`` of ``disp`` copied to ``out`` and filled along the row."""
    w = disp.shape[1]
    for v in range(row_start, row_stop):
        for u in range(w):   # (a loop: an array-to-array slice assignment compiles for seconds)
            out[v, u] = disp[v, u]
        _fill_line(out[v], max_gap, discon, extrapolate)


def interpolate_gaps(disp: np.ndarray, max_gap: int, *, extrapolate: bool = False,
                     discontinuity: float = DISCONTINUITY_THRESHOLD,
                     workspace=None) -> np.ndarray:
    """Fill runs of at most ``max_gap`` invalid pixels between two valid ones, rows first,
    then columns.

    A run is filled with the mean of its two ends when they differ by less than
    ``discontinuity`` pixels, otherwise with the smaller one (the background).
    With ``extrapolate`` the first/last valid value of each row and column is also
    copied up to ``max_gap`` pixels towards the image border.
    Returns a new map, or the :class:`~canopy_stereo.elas.workspace.Workspace`'s
    (overwritten by its next use) when one is given.
    """
    disp = np.ascontiguousarray(disp, np.float32)
    out = np.empty_like(disp) if workspace is None else \
        workspace.array("interpolated", disp.shape, np.float32)
    h, w = disp.shape
    args = (int(max_gap), float(discontinuity), bool(extrapolate))
    # rows in row bands, then columns in column bands (each line is filled on its own)
    run_row_bands((_fill_rows, h, (disp, *args, out)))
    run_row_bands((_fill_columns, w, (out, *args)))
    return out


@njit(cache=True, inline="always")
def _mean_weight(d, c, linear):
    """Weight of tap value ``d`` for centre ``c`` (0 for an invalid tap): the step
    weights, or the ramp with ``linear`` (a loop-invariant bool: LLVM compiles one
    branch-free loop per value). Bit for bit the former single formula
    ``(l * ramp + (1 - l) * step) * valid`` with ``l`` 0.0 or 1.0, for finite maps."""
    delta = abs(d - c)
    if linear:
        weight = max(np.float32(0.0), np.float32(4.0) - delta)
    else:
        weight = (np.float32(2.0) * np.float32(delta < 8.0)
                  + np.float32(2.0) * np.float32(delta < 2.0))
    return weight * np.float32(d >= 0)


@njit(cache=True, nogil=True)
def _adaptive_mean_rows(disp, linear, before, after, rows, row_start, row_stop):
    """Rows pass (taps along u) of rows ``[row_start, row_stop)`` into ``rows``; invalid taps
    and taps outside the image weigh nothing. The tap counts are arguments, not constants,
    so that LLVM does not unroll the tap loops (which multiplied the compile time by ten)."""
    w = disp.shape[1]
    # a padded copy of each row; tap k of pixel u is line[u + k]
    line = np.full(w + before + after, -1.0, dtype=np.float32)
    s = np.empty(w, dtype=np.float32)
    sw = np.empty(w, dtype=np.float32)
    for v in range(row_start, row_stop):
        centre = disp[v]
        for u in range(w):
            line[before + u] = centre[u]
        if not linear:      # sixteen pixels at a time in registers, the rest as below
            done = w - w % MEAN_LANES
            for u in range(0, done, MEAN_LANES):
                step_mean16(line, u, 1, before + after + 1, centre, u, rows[v], u)
            for u in range(done, w):
                rows[v, u] = _step_mean_pixel(line, u, 1, before + after + 1, centre[u])
            continue
        for u in range(w):
            s[u] = 0.0
            sw[u] = 0.0
        for k in range(before + after + 1):
            tap = line[k:k + w]
            for u in range(w):
                wt = _mean_weight(tap[u], centre[u], linear)
                s[u] += wt * tap[u]
                sw[u] += wt
        _mean_quotient(s, sw, centre, rows[v])


@njit(cache=True, nogil=True, error_model="numpy")
def _step_mean_pixel(taps, first, tap_stride, n_taps, c):
    """One pixel of :func:`~canopy_stereo.elas.simd.step_mean16` (the same float32 steps;
    numpy's error model: 0/0 where the centre is invalid is not stored)."""
    s = np.float32(0.0)
    sw = np.float32(0.0)
    for k in range(n_taps):
        t = taps[first + k * tap_stride]
        wt = _mean_weight(t, c, False)
        s += wt * t
        sw += wt
    q = s / sw
    return q if c >= 0 else c


@njit(cache=True, nogil=True, error_model="numpy")
def _mean_quotient(s, sw, centre, dst):
    """``dst[u] = s[u] / sw[u]`` where ``centre[u]`` is valid, else ``centre[u]``.

    The quotient is computed for every pixel and then selected (0/0 = NaN where the
    centre is invalid is never stored; a valid centre weighs itself, so ``sw > 0``
    there): one vector division for many pixels instead of one division and branch per
    pixel (numpy's error model: no zero-division check, which kept it scalar)."""
    for u in range(dst.shape[0]):
        q = s[u] / sw[u]
        dst[u] = q if centre[u] >= 0 else centre[u]


@njit(cache=True, nogil=True)
def _adaptive_mean_columns(rows, linear, before, after, out, row_start, row_stop):
    """Columns pass (taps along v) of output rows ``[row_start, row_stop)``, accumulating
    whole rows ``v-before .. v+after`` of the rows pass (contiguous, vectorises over u)."""
    h, w = rows.shape
    s = np.empty(w, dtype=np.float32)
    sw = np.empty(w, dtype=np.float32)
    flat = rows.reshape(-1)
    for v in range(row_start, row_stop):
        centre = rows[v]
        if not linear and v >= before and v + after < h:
            # all taps inside: sixteen pixels at a time in registers, the rest one by one
            done = w - w % MEAN_LANES
            first = (v - before) * w
            for u in range(0, done, MEAN_LANES):
                step_mean16(flat, first + u, w, before + after + 1, centre, u, out[v], u)
            for u in range(done, w):
                out[v, u] = _step_mean_pixel(flat, first + u, w, before + after + 1, centre[u])
            continue
        for u in range(w):
            s[u] = 0.0
            sw[u] = 0.0
        for vv in range(max(v - before, 0), min(v + after + 1, h)):
            tap = rows[vv]
            for u in range(w):
                wt = _mean_weight(tap[u], centre[u], linear)
                s[u] += wt * tap[u]
                sw[u] += wt
        _mean_quotient(s, sw, centre, out[v])


def adaptive_mean(disp: np.ndarray, linear: bool = False, *, workspace=None) -> np.ndarray:
    """Separable 8-tap adaptive mean (rows, then columns; taps at -4..+3).

    Each valid tap is weighted by its difference ``dd`` to the centre: 4 if
    ``|dd| < 2``, 2 if ``2 <= |dd| < 8``, else 0 (the original as compiled), or
    ``max(0, 4 - |dd|)`` with ``linear``. Invalid pixels stay invalid. Returns a new
    map; the rows pass's scratch comes from ``workspace`` when given. Each pass runs in
    row bands (:func:`~canopy_stereo.elas.parallel.run_row_bands`): every row is
    computed by the same code whatever the thread count.
    """
    disp = np.ascontiguousarray(disp, np.float32)
    rows = np.empty_like(disp) if workspace is None else \
        workspace.array("adaptive_mean_rows", disp.shape, np.float32)
    out = np.empty_like(disp)
    h = disp.shape[0]
    linear = bool(linear)
    run_row_bands((_adaptive_mean_rows, h,
                   (disp, linear, MEAN_TAPS_BEFORE, MEAN_TAPS_AFTER, rows)))
    run_row_bands((_adaptive_mean_columns, h,
                   (rows, linear, MEAN_TAPS_BEFORE, MEAN_TAPS_AFTER, out)))
    return out


#: An optimal 16-comparator sorting network for 7 values (checked exhaustively on
#: all 0/1 inputs in the tests).
MEDIAN_NETWORK = ((0, 6), (2, 3), (4, 5), (0, 2), (1, 4), (3, 6), (0, 1), (2, 5), (3, 4),
                  (1, 2), (4, 6), (2, 3), (4, 5), (1, 2), (3, 4), (5, 6))


@njit(cache=True, inline="always")
def _valid_or_inf(x):
    return x if x >= 0 else np.float32(np.inf)


@njit(cache=True, inline="always")
def _median7(t0, t1, t2, t3, t4, t5, t6):
    """Median of the valid (>= 0) values among seven taps (the upper one of an even
    count): invalid taps become +inf and sort to the end of :data:`MEDIAN_NETWORK`."""
    n = ((t0 >= 0) + (t1 >= 0) + (t2 >= 0) + (t3 >= 0) + (t4 >= 0) + (t5 >= 0)
         + (t6 >= 0))
    x0, x1, x2, x3 = _valid_or_inf(t0), _valid_or_inf(t1), _valid_or_inf(t2), _valid_or_inf(t3)
    x4, x5, x6 = _valid_or_inf(t4), _valid_or_inf(t5), _valid_or_inf(t6)
    # the comparators of MEDIAN_NETWORK, in order
    x0, x6 = min(x0, x6), max(x0, x6)
    x2, x3 = min(x2, x3), max(x2, x3)
    x4, x5 = min(x4, x5), max(x4, x5)
    x0, x2 = min(x0, x2), max(x0, x2)
    x1, x4 = min(x1, x4), max(x1, x4)
    x3, x6 = min(x3, x6), max(x3, x6)
    x0, x1 = min(x0, x1), max(x0, x1)
    x2, x5 = min(x2, x5), max(x2, x5)
    x3, x4 = min(x3, x4), max(x3, x4)
    x1, x2 = min(x1, x2), max(x1, x2)
    x4, x6 = min(x4, x6), max(x4, x6)
    x2, x3 = min(x2, x3), max(x2, x3)
    x4, x5 = min(x4, x5), max(x4, x5)
    x1, x2 = min(x1, x2), max(x1, x2)
    x3, x4 = min(x3, x4), max(x3, x4)
    x5, x6 = min(x5, x6), max(x5, x6)
    k = n // 2      # (selects, not branches: the pixel loops vectorise)
    low = x1 if k == 1 else x0
    high = x3 if k == 3 else x2
    return high if k >= 2 else low


@njit(cache=True, nogil=True)
def _median(disp, radius, rows):
    """Rows pass (into ``rows``) then columns pass of the 7-tap median of valid values."""
    h, w = disp.shape
    line = np.full(w + 2 * radius, -1.0, dtype=np.float32)
    for v in range(h):
        src = disp[v]
        for u in range(w):
            line[radius + u] = src[u]
        dst = rows[v]
        for u in range(w):
            m = _median7(line[u], line[u + 1], line[u + 2], line[u + 3], line[u + 4],
                         line[u + 5], line[u + 6])
            dst[u] = m if src[u] >= 0 else src[u]
    out = np.empty_like(rows)       # (every pixel is written below)
    pad = np.full(w, -1.0, dtype=np.float32)
    for v in range(h):
        centre = rows[v]
        r0 = rows[v - 3] if v >= 3 else pad
        r1 = rows[v - 2] if v >= 2 else pad
        r2 = rows[v - 1] if v >= 1 else pad
        r4 = rows[v + 1] if v + 1 < h else pad
        r5 = rows[v + 2] if v + 2 < h else pad
        r6 = rows[v + 3] if v + 3 < h else pad
        dst = out[v]
        for u in range(w):
            m = _median7(r0[u], r1[u], r2[u], centre[u], r4[u], r5[u], r6[u])
            dst[u] = m if centre[u] >= 0 else centre[u]
    return out


def median_filter(disp: np.ndarray, *, workspace=None) -> np.ndarray:
    """Separable 7-tap median of the valid taps (rows, then columns); invalid stays invalid.

    Returns a new map; the rows pass's scratch comes from ``workspace`` when given.
    """
    disp = np.ascontiguousarray(disp, np.float32)
    rows = np.empty_like(disp) if workspace is None else \
        workspace.array("median_rows", disp.shape, np.float32)
    return _median(disp, MEDIAN_RADIUS, rows)
