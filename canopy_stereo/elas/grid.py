"""ELAS stage 5: the disparity grid, coarse per-cell candidate sets.

The image is split into ``grid_size`` x ``grid_size`` pixel cells (the last row and
column of cells may be smaller). A support point at ``(x, v)`` of an image (``x = u``
for the left image, ``u - d`` for the right) adds ``d-1, d, d+1`` (clipped to the
search range) to its cell; then every cell takes the union of its 3x3 neighbourhood.
The candidates of a cell are its set disparities in increasing order.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _grid(points, right_image, width, height, grid_size, disp_min, disp_max, seed, across,
          lists, counts):
    gw = (width + grid_size - 1) // grid_size
    gh = (height + grid_size - 1) // grid_size
    ndisp = disp_max + 1
    seed[:, :, :] = 0
    for p in range(points.shape[0]):
        d = points[p, 2]
        x = points[p, 0] - d if right_image else points[p, 0]
        y = points[p, 1]
        if x < 0 or x >= width or y < 0 or y >= height:
            continue
        gx = x // grid_size
        gy = y // grid_size
        for dd in range(max(d - 1, disp_min), min(d + 1, disp_max) + 1):
            seed[gy, gx, dd] = 1
    # 3x3 union, separably: along x, then along y
    across[:, :, :] = 0
    for gy in range(gh):
        for gx in range(gw):
            dst = across[gy, gx]
            for nx in range(max(gx - 1, 0), min(gx + 2, gw)):
                src = seed[gy, nx]
                for dd in range(ndisp):
                    dst[dd] |= src[dd]
    lists[:, :, :] = 0
    cell = np.zeros(ndisp, dtype=np.uint8)
    for gy in range(gh):
        for gx in range(gw):
            for dd in range(ndisp):
                cell[dd] = 0
            for ny in range(max(gy - 1, 0), min(gy + 2, gh)):
                src = across[ny, gx]
                for dd in range(ndisp):
                    cell[dd] |= src[dd]
            n = 0
            for dd in range(disp_min, ndisp):
                if cell[dd]:
                    lists[gy, gx, n] = dd
                    n += 1
            counts[gy, gx] = n
    return lists, counts


def disparity_grid(points: np.ndarray, image_size: tuple[int, int], grid_size: int,
                   disp_min: int, disp_max: int, *, right_image: bool = False, workspace=None):
    """Per-cell candidate disparities.

    Args:
        points: int (N, 3) support points ``(u, v, d)`` in left-image pixels.
        image_size: ``(width, height)`` in pixels.
        grid_size: cell size in pixels.
        disp_min, disp_max: search range (candidates are clipped to it).
        right_image: place points at ``(u - d, v)`` (the right image's grid).
        workspace: a :class:`~canopy_stereo.elas.workspace.Workspace` to take the
            arrays from (overwritten by its next use); fresh arrays when None.

    Returns:
        ``(lists, counts)``: cell ``(gy, gx)`` (pixels ``gx*grid_size ...``,
        ``gy*grid_size ...``) has the candidates ``lists[gy, gx, :counts[gy, gx]]``
        (int32, increasing); ``lists`` is (gh, gw, disp_max+1).
    """
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.int64).reshape(-1, 3))
    w, h = (int(x) for x in image_size)
    grid_size = int(grid_size)
    shape = ((h + grid_size - 1) // grid_size, (w + grid_size - 1) // grid_size, int(disp_max) + 1)
    if workspace is None:
        arrays = (np.empty(shape, np.uint8), np.empty(shape, np.uint8), np.empty(shape, np.int32),
                  np.empty(shape[:2], np.int32))
    else:
        arrays = (workspace.array("grid_seed", shape, np.uint8),
                  workspace.array("grid_across", shape, np.uint8),
                  workspace.array("grid_lists", shape, np.int32),
                  workspace.array("grid_counts", shape[:2], np.int32))
    _grid(pts, bool(right_image), w, h, grid_size, int(disp_min), int(disp_max), *arrays)
    return arrays[2], arrays[3]


@njit(cache=True, nogil=True)
def _ranks_into(lists, counts, ranks):
    gh, gw, size = ranks.shape
    for gy in range(gh):
        for gx in range(gw):
            cell = lists[gy, gx]
            n = counts[gy, gx]
            dst = ranks[gy, gx]
            j = 0
            for d in range(size):
                while j < n and cell[j] < d:
                    j += 1
                dst[d] = j


def candidate_ranks(lists: np.ndarray, counts: np.ndarray, *, workspace=None) -> np.ndarray:
    """Per cell, how many of its candidates lie below each disparity.

    Args:
        lists, counts: a :func:`disparity_grid` (lists (gh, gw, D) int32, increasing).
        workspace: a :class:`~canopy_stereo.elas.workspace.Workspace` to take the
            array from (overwritten by its next use); a fresh array when None.

    Returns:
        int16 (gh, gw, D + 1): ``ranks[gy, gx, d]`` is the number of candidates of cell
        ``(gy, gx)`` smaller than ``d`` (``d = 0 .. D``), so the candidates in
        ``[a, b]`` are ``lists[gy, gx, ranks[a]:ranks[b + 1]]`` (D <= 32001: int16).
    """
    shape = (lists.shape[0], lists.shape[1], lists.shape[2] + 1)
    ranks = np.empty(shape, np.int16) if workspace is None else \
        workspace.array("grid_ranks", shape, np.int16)
    _ranks_into(lists, counts, ranks)
    return ranks
