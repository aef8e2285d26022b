"""ELAS stage 2: support points, sparse robust matches on a regular candidate grid.

A candidate sits every ``step`` pixels (cell ``(i, j)`` is pixel ``(u, v) = (j*step,
i*step)``) with ``5 <= u <= W-6`` and ``5 <= v <= H-6``. Its cost at disparity ``d``
is the descriptor SAD summed over the four pixels ``(u +- 2, v +- 2)``. A candidate
survives when

* its own descriptor's texture is at least ``support_texture``,
* at least :data:`~canopy_stereo.elas.params.MIN_SUPPORT_DISPARITIES` disparities
  keep all four samples inside the descriptor area,
* its best cost is below ``support_threshold`` times the second best (over all
  other disparities, neighbours of the best included),
* matching back from the right image lands within ``lr_threshold``.

Then, on the grid of candidate cells, two filters run in the original's order
(columns outer, rows inner, updating in place): inconsistent points (too few
similar neighbours) and redundant points (a similar neighbour on both sides, first
along columns, then along rows).

Support points are returned as int32 rows ``(u, v, d)`` in left-image pixels.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from canopy_stereo.elas.descriptor import BORDER
from canopy_stereo.elas.parallel import run_row_bands
from canopy_stereo.elas.params import MIN_SUPPORT_DISPARITIES
from canopy_stereo.elas.simd import (
    DESC_BYTES,
    PSADBW_WIDTH,
    SUPPORT_LANES,
    sad64,
    sad64_chunks_first_two_min,
)

#: Offset (pixels) of the four descriptor samples from the candidate, both axes.
SUPPORT_SAMPLE_OFFSET = 2
#: First and last valid candidate coordinate: ``MARGIN <= u <= W-1-MARGIN``.
SUPPORT_MARGIN = BORDER + SUPPORT_SAMPLE_OFFSET
#: Redundancy filter: look this many cells along each direction ...
REDUNDANT_MAX_DIST = 5
#: ... for a point whose disparity differs by at most this much.
REDUNDANT_THRESHOLD = 1


#: Bytes of a candidate's cost vector: its four descriptors side by side.
SUPPORT_BYTES = 4 * DESC_BYTES


@njit(cache=True, inline="always")
def _sample_row(words, v, dst):
    """Cost vectors of candidate row ``v``: ``dst[x]`` (8 uint64 = 64 bytes) holds the
    descriptors at ``(x - 2, v - 2)``, ``(x + 2, v - 2)``, ``(x - 2, v + 2)``,
    ``(x + 2, v + 2)`` for ``2 <= x < W - 2`` (other columns are left as they are).

    ``words`` is the (H, W, 2) uint64 view of the descriptors, ``dst`` (W, 8) uint64.
    """
    w = words.shape[1]
    off = SUPPORT_SAMPLE_OFFSET
    top = words[v - off]
    bottom = words[v + off]
    for x in range(off, w - off):
        dst[x, 0] = top[x - off, 0]
        dst[x, 1] = top[x - off, 1]
        dst[x, 2] = top[x + off, 0]
        dst[x, 3] = top[x + off, 1]
        dst[x, 4] = bottom[x - off, 0]
        dst[x, 5] = bottom[x - off, 1]
        dst[x, 6] = bottom[x + off, 0]
        dst[x, 7] = bottom[x + off, 1]


@njit(cache=True, inline="always")
def _lowest_two_scalar(flat_own, flat_other, a, sign, dmin, dmax):
    """``(best, second, best_d)`` of the costs at ``d = dmin..dmax``: the lowest cost, the
    second lowest (of the multiset of costs) and the first ``d`` with the lowest cost, one
    64-byte SAD at a time (branch-free: a new best pushes the old one to second)."""
    return _fold_lowest_two(flat_own, flat_other, a, sign, dmin, dmax, np.int64(2147483647),
                            np.int64(2147483647), -1)


@njit(cache=True, inline="always")
def _fold_lowest_two(flat_own, flat_other, a, sign, dmin, dmax, best_e, second_e, best_d):
    """``(best, second, best_d)`` carried on over ``d = dmin..dmax``, one 64-byte SAD at a
    time (branch-free: a new best pushes the old one to second)."""
    for d in range(dmin, dmax + 1):
        e = np.int64(sad64(flat_own, a, flat_other, a - sign * d * SUPPORT_BYTES))
        lower = e < best_e
        second_e = best_e if lower else min(e, second_e)
        best_d = d if lower else best_d
        best_e = e if lower else best_e
    return best_e, second_e, best_d


#: Zero columns on each side of a chunk-major row buffer (a group of 8 disparities may
#: reach past the last valid column).
CHUNK_PAD = SUPPORT_LANES


@njit(cache=True, inline="always")
def _sample_row_chunks(words, v, dst):
    """:func:`_sample_row` stored chunk-major: ``dst[c, CHUNK_PAD + x]`` (uint64 (8,
    W + 2 CHUNK_PAD)) is qword ``c`` of column ``x``'s cost vector."""
    w = words.shape[1]
    off = SUPPORT_SAMPLE_OFFSET
    top = words[v - off]
    bottom = words[v + off]
    for k in range(2):
        for x in range(off, w - off):
            dst[k, CHUNK_PAD + x] = top[x - off, k]
        for x in range(off, w - off):
            dst[2 + k, CHUNK_PAD + x] = top[x + off, k]
        for x in range(off, w - off):
            dst[4 + k, CHUNK_PAD + x] = bottom[x - off, k]
        for x in range(off, w - off):
            dst[6 + k, CHUNK_PAD + x] = bottom[x + off, k]


@njit(cache=True, inline="always")
def _lowest_two_chunks(buf_own, buf_other, u, sign, dmin, dmax):
    """:func:`_lowest_two_scalar` of column ``u`` over chunk-major row buffers
    (:func:`_sample_row_chunks`, flattened), 8 disparities per group
    (:func:`~canopy_stereo.elas.simd.sad64_chunks_first_two_min`), the lanes merged
    exactly (lowest, then the multiset's second lowest, ties to the first ``d``)."""
    stride = buf_own.shape[0] // SUPPORT_LANES
    n = dmax - dmin + 1
    groups = (n + SUPPORT_LANES - 1) // SUPPORT_LANES
    if sign > 0:    # other column u - dmin - j: lane k of group g is j = 8 g + 7 - k
        r = sad64_chunks_first_two_min(buf_own, CHUNK_PAD + u, buf_other,
                                       CHUNK_PAD + u - dmin - (SUPPORT_LANES - 1), stride,
                                       -SUPPORT_LANES, groups, SUPPORT_LANES - 1, -1, n)
    else:           # other column u + dmin + j: lane k of group g is j = 8 g + k
        r = sad64_chunks_first_two_min(buf_own, CHUNK_PAD + u, buf_other, CHUNK_PAD + u + dmin,
                                       stride, SUPPORT_LANES, groups, 0, 1, n)
    best_e = np.int64(2147483647)
    second_e = np.int64(2147483647)
    best_j = -1
    for k in range(SUPPORT_LANES):
        e = r[k]
        j = r[2 * SUPPORT_LANES + k]
        lower = e < best_e
        second_e = best_e if lower else min(e, second_e)
        if lower or (e == best_e and j < best_j):
            best_j = j
        best_e = e if lower else best_e
    for k in range(SUPPORT_LANES):
        second_e = min(second_e, r[SUPPORT_LANES + k])
    return best_e, second_e, (dmin + best_j if best_j >= 0 else -1)


@njit(cache=True, inline="always")
def _lowest_two_interleaved(buf_own, buf_other, u, sign, dmin, dmax):
    """:func:`_lowest_two_scalar` of column ``u`` over interleaved row buffers
    (:func:`_sample_row`, flattened to bytes)."""
    return _lowest_two_scalar(buf_own, buf_other, u * SUPPORT_BYTES, sign, dmin, dmax)


@njit(cache=True)
def _row_buffer_chunks(w):
    return np.zeros(SUPPORT_LANES * (w + 2 * CHUNK_PAD), np.uint64)


@njit(cache=True)
def _row_buffer_interleaved(w):
    return np.zeros(w * SUPPORT_BYTES, np.uint8)


@njit(cache=True, inline="always")
def _sample_into_chunks(words, v, flat):
    _sample_row_chunks(words, v, flat.reshape(SUPPORT_LANES, flat.shape[0] // SUPPORT_LANES))


@njit(cache=True, inline="always")
def _sample_into_interleaved(words, v, flat):
    w = words.shape[1]
    _sample_row(words, v, flat.view(np.uint64).reshape(w, SUPPORT_BYTES // 8))


#: The row buffers and the lowest-two search compiled here: chunk-major buffers and eight
#: disparities per vector with AVX-512BW, interleaved 64-byte vectors one SAD at a time
#: elsewhere.
if PSADBW_WIDTH == 64:
    _row_buffer, _sample_into, _lowest_two = (_row_buffer_chunks, _sample_into_chunks,
                                              _lowest_two_chunks)
else:
    _row_buffer, _sample_into, _lowest_two = (_row_buffer_interleaved, _sample_into_interleaved,
                                              _lowest_two_interleaved)


@njit(cache=True, inline="always")
def _candidate_disparity(flat_own, flat_other, texture_own, width, u, v, sign,
                         disp_min, disp_max, support_texture, support_threshold):
    """Best disparity of candidate (u, v) of the *own* image, or -1.

    ``flat_own``/``flat_other`` are the candidate row's cost vectors (the row buffers
    of :func:`_sample_into`). ``sign`` is +1 for the left image (match at ``u - d`` in
    the right image) and -1 for the right image (match at ``u + d``).
    """
    off = SUPPORT_SAMPLE_OFFSET
    if texture_own[v, u] < support_texture:
        return -1
    # all four samples (x +- off) must stay in the descriptor area [BORDER, width-1-BORDER]
    if sign > 0:
        dmax = min(disp_max, u - off - BORDER)
    else:
        dmax = min(disp_max, width - 1 - BORDER - off - u)
    dmin = max(disp_min, 0)
    if dmax - dmin + 1 < MIN_SUPPORT_DISPARITIES:
        return -1
    # at least MIN_SUPPORT_DISPARITIES (> 1) costs are seen, so both lowest exist
    best_e, second_e, best_d = _lowest_two(flat_own, flat_other, u, sign, dmin, dmax)
    if np.float32(best_e) < support_threshold * np.float32(second_e):
        return best_d
    return -1


@njit(cache=True, nogil=True)
def _candidate_rows(words_left, words_right, tex_left, tex_right, step, disp_min, disp_max,
                    support_texture, support_threshold, lr_threshold, grid, row_start, row_stop):
    """Candidate cells of rows ``[row_start, row_stop)`` of :func:`candidate_grid`.

    Each candidate row's cost vectors (:func:`_sample_into`) are gathered into two
    row buffers that this call reuses for all its rows (gathering whole images cost
    ~8 MB of fresh pages per frame at 640x480).
    """
    h, w, _ = words_left.shape
    flat_l = _row_buffer(w)
    flat_r = _row_buffer(w)
    cols = grid.shape[1]
    for i in range(row_start, row_stop):
        v = i * step
        if v < SUPPORT_MARGIN or v > h - 1 - SUPPORT_MARGIN:
            continue
        _sample_into(words_left, v, flat_l)
        _sample_into(words_right, v, flat_r)
        for j in range(cols):
            u = j * step
            if u < SUPPORT_MARGIN or u > w - 1 - SUPPORT_MARGIN:
                continue
            d = _candidate_disparity(flat_l, flat_r, tex_left, w, u, v, 1, disp_min,
                                     disp_max, support_texture, support_threshold)
            if d < 0:
                continue
            d_back = _candidate_disparity(flat_r, flat_l, tex_right, w, u - d, v, -1,
                                          disp_min, disp_max, support_texture, support_threshold)
            if d_back >= 0 and abs(d - d_back) <= lr_threshold:
                grid[i, j] = d


def candidate_grid(desc_left, desc_right, tex_left, tex_right, step, disp_min, disp_max,
                   support_texture, support_threshold, lr_threshold) -> np.ndarray:
    """Left-right checked candidate disparities, int32 (rows, cols) cells, -1 = none.

    ``desc_*`` are uint8 (H, W, 16) descriptors, ``tex_*`` int32 (H, W) textures;
    cell ``(i, j)`` is pixel ``(j*step, i*step)``. Each candidate row's four-sample
    cost vectors are gathered first, so that one candidate cost is one 64-byte SAD;
    rows of cells run in parallel.
    """
    h, w = desc_left.shape[:2]
    rows, cols = (h - 1) // step + 1, (w - 1) // step + 1
    grid = np.full((rows, cols), -1, dtype=np.int32)
    words = [np.ascontiguousarray(d).reshape(h, w * DESC_BYTES).view(np.uint64).reshape(h, w, 2)
             for d in (desc_left, desc_right)]
    args = (words[0], words[1], tex_left, tex_right, int(step), int(disp_min), int(disp_max),
            int(support_texture), np.float32(support_threshold), int(lr_threshold), grid)
    run_row_bands((_candidate_rows, rows, args))
    return grid


@njit(cache=True, nogil=True)
def remove_inconsistent(grid, window, threshold, min_support):
    """In place: drop points with fewer than ``min_support`` points (itself included)
    within ``window`` cells whose disparity differs by at most ``threshold``."""
    rows, cols = grid.shape
    for j in range(cols):
        for i in range(rows):
            d = grid[i, j]
            if d < 0:
                continue
            # counted row by row (contiguous), each row at once; enough support ends
            # the count (only "fewer than min_support" matters)
            support = 0
            j_lo, j_hi = max(j - window, 0), min(j + window + 1, cols)
            for i2 in range(max(i - window, 0), min(i + window + 1, rows)):
                row = grid[i2]
                for j2 in range(j_lo, j_hi):
                    d2 = row[j2]
                    support += (d2 >= 0) & (abs(d - d2) <= threshold)
                if support >= min_support:
                    break
            if support < min_support:
                grid[i, j] = -1
    return grid


@njit(cache=True, nogil=True)
def remove_redundant(grid, max_dist, threshold, vertical):
    """In place: drop points that have a point with ``|dd| <= threshold`` within
    ``max_dist`` cells on *both* sides (along columns if ``vertical`` else along rows)."""
    rows, cols = grid.shape
    di = 1 if vertical else 0
    dj = 0 if vertical else 1
    for j in range(cols):
        for i in range(rows):
            d = grid[i, j]
            if d < 0:
                continue
            redundant = True
            for side in (-1, 1):
                found = False
                i2 = i
                j2 = j
                for _ in range(max_dist):
                    i2 += side * di
                    j2 += side * dj
                    if i2 < 0 or i2 >= rows or j2 < 0 or j2 >= cols:
                        break
                    d2 = grid[i2, j2]
                    if d2 >= 0 and abs(d - d2) <= threshold:
                        found = True
                        break
                if not found:
                    redundant = False
                    break
            if redundant:
                grid[i, j] = -1
    return grid


def grid_to_points(grid: np.ndarray, step: int) -> np.ndarray:
    """int32 (N, 3) rows ``(u, v, d)`` of the valid cells, columns outer, rows inner."""
    jj, ii = np.nonzero(grid.T >= 0)
    d = grid[ii, jj]
    return np.stack([jj * step, ii * step, d], axis=1).astype(np.int32)


def corner_points(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """The 4 image corners with the disparity of their nearest support point, and
    the 4 points ``(u_c + d, v_c, d)`` that put a vertex on each right-image corner.

    Returns int32 (8, 3) rows ``(u, v, d)`` (empty when ``points`` is empty).
    """
    if len(points) == 0:
        return np.zeros((0, 3), np.int32)
    corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]],
                       dtype=np.int64)
    uv = points[:, :2].astype(np.int64)
    dist2 = ((uv[None, :, :] - corners[:, None, :]) ** 2).sum(axis=2)
    d = points[np.argmin(dist2, axis=1), 2].astype(np.int64)
    left = np.column_stack([corners, d])
    right = np.column_stack([corners[:, 0] + d, corners[:, 1], d])
    return np.vstack([left, right]).astype(np.int32)


def support_points(desc_left, desc_right, tex_left, tex_right, params) -> np.ndarray:
    """Support points of a pair, int32 (N, 3) rows ``(u, v, d)`` (left-image pixels).

    ``params`` is an :class:`~canopy_stereo.elas.params.ElasParams`; the corner
    points of ``add_corners`` are appended last.
    """
    step = int(params.candidate_stepsize)
    grid = candidate_grid(desc_left, desc_right, tex_left, tex_right, step, params.disp_min,
                          params.disp_max, params.support_texture, params.support_threshold,
                          params.lr_threshold)
    remove_inconsistent(grid, int(params.incon_window_size), int(params.incon_threshold),
                        int(params.incon_min_support))
    remove_redundant(grid, REDUNDANT_MAX_DIST, REDUNDANT_THRESHOLD, True)
    remove_redundant(grid, REDUNDANT_MAX_DIST, REDUNDANT_THRESHOLD, False)
    points = grid_to_points(grid, step)
    if params.add_corners:
        h, w = desc_left.shape[:2]
        points = np.vstack([points, corner_points(points, w, h)])
    return points
