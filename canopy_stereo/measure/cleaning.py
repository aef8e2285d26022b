"""Cleaning a reconstructed canopy of matching debris, before its extents are measured.

Stereo matching leaves background depths bled onto the plant's rim, pieces cut
off by depth jumps, noise along the lines of sight, isolated points and small
clusters floating off the canopy; each function here removes one of them.
Pixel masks are (H, W) bool on the organized cloud's grid; points are world units.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.measure.instances import connected_surface_parts, neighbour_spacing


def _local_median(values: np.ndarray, sample: np.ndarray, at: np.ndarray, window: int,
                  step: int = 3) -> np.ndarray:
    """(H, W) median of ``values`` over the ``sample`` pixels in a ``window`` square
    around each pixel of ``at`` (every ``step``-th offset); NaN elsewhere or when
    there is no sample."""
    r = window // 2
    h, w = values.shape
    vals = np.where(sample, values, np.nan)
    pad = np.pad(vals, r, constant_values=np.nan)
    vs, us = np.nonzero(at)
    offs = range(0, 2 * r + 1, step)
    stack = np.stack([pad[vs + dv, us + du] for dv in offs for du in offs], axis=1)
    out = np.full((h, w), np.nan)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[vs, us] = np.nanmedian(stack, axis=1)
    return out


def clean_canopy(organized, plant, *, background=None, viewpoint=None, jump_factor: float = 8.0,
                  min_part: int = 10, window: int = 31, all_plant=None):
    """Plant pixels without matching debris.

    Drops pieces cut off from the rest by depth jumps when smaller than
    ``min_part`` pixels, and,
    with a ``viewpoint`` (camera centre) and a ``background`` mask, points whose
    distance is nearer the median distance of the background pixels than that
    of the plant pixels (``all_plant``, default ``plant``) in a ``window``-pixel
    square around them (background depths bled onto the plant's rim; where the
    plant touches its ground both are alike and the points stay).
    """
    keep = plant.copy()
    if viewpoint is not None and background is not None and background.any():
        dist = np.linalg.norm(organized - np.asarray(viewpoint, np.float64), axis=-1)
        finite = np.isfinite(dist)
        local_bg = _local_median(dist, background & finite, plant, window)
        # the plant's own distance around a pixel: all plant pixels with a point
        local_plant = _local_median(dist, all_plant if all_plant is not None else plant, plant, window)
        with np.errstate(invalid="ignore"):
            debris = np.isfinite(local_bg) & (np.abs(dist - local_bg) < np.abs(dist - local_plant))
        keep &= ~debris
    spacing = neighbour_spacing(organized, keep)
    if np.isfinite(spacing) and spacing > 0:
        labels = connected_surface_parts(organized, keep, jump_factor * spacing)
        counts = np.bincount(labels.ravel())
        counts[0] = 0
        big = np.nonzero(counts >= min_part)[0]
        keep = np.isin(labels, big)
    return keep if keep.sum() >= 3 else plant


def median_along_rays(organized: np.ndarray, keep: np.ndarray, viewpoint, *, radius: int = 3) -> np.ndarray:
    """Points of ``keep`` (N, 3) with their distance from ``viewpoint`` replaced
    by the median over their ``(2 radius + 1)^2`` neighbours in ``keep``.

    Each point stays on its own line of sight, where a reconstruction errs, so
    this removes matching noise (which would widen the extents) without
    moving points across the image.
    """
    C = np.asarray(viewpoint, np.float64).reshape(3)
    rel = np.where(keep[..., None], organized - C, np.nan)
    dist = np.linalg.norm(rel, axis=-1)
    h, w = dist.shape
    pad = np.pad(dist, radius, constant_values=np.nan)
    vs, us = np.nonzero(keep)
    windows = np.stack([pad[vs + dv, us + du] for dv in range(2 * radius + 1)
                        for du in range(2 * radius + 1)], axis=1)
    med = np.nanmedian(windows, axis=1)
    return C + rel[vs, us] * (med / dist[vs, us])[:, None]


def drop_isolated_points(points: np.ndarray, k: int = 8, *, factor: float = 4.0) -> np.ndarray:
    """Points whose mean distance to their ``k`` nearest neighbours is at most
    ``factor`` times the median of that distance (statistical outlier removal)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, np.float64)
    if len(P) <= 2 * k:
        return P
    d, _ = cKDTree(P).query(P, k=k + 1)
    mean_d = d[:, 1:].mean(axis=1)
    return P[mean_d <= factor * np.median(mean_d)]


def drop_detached_clusters(points: np.ndarray, cell: float, *, min_fraction: float = 0.002,
                           candidates: np.ndarray | None = None) -> np.ndarray:
    """Keep-mask (N,) of points not in small clusters detached from the rest.

    Points are binned into cubic cells of edge ``cell``; occupied cells touching
    (26-neighbourhood) form clusters. Clusters holding fewer than
    ``min_fraction`` of the points are dropped: stray matches floating off the
    canopy (a mismatched sliver of a leaf seen edge-on lands tens of
    centimetres behind it), which would set the extents. With ``candidates``
    (N,) bool, only those points may be dropped.
    """
    from scipy import ndimage

    P = np.asarray(points, np.float64)
    keep = np.ones(len(P), bool)
    if len(P) < 10 or not (cell > 0):
        return keep
    idx = np.floor(P / cell).astype(np.int64)  # one grid of the world frame (as the voxel volume's)
    idx -= idx.min(axis=0)
    shape = idx.max(axis=0) + 1
    if np.prod(shape) > 50_000_000:  # absurd spread for the cell: leave the points alone
        return keep
    grid = np.zeros(shape, bool)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return keep
    point_label = labels[idx[:, 0], idx[:, 1], idx[:, 2]]
    counts = np.bincount(point_label, minlength=n + 1)
    small = counts[point_label] < min_fraction * len(P)
    if candidates is not None:
        small &= candidates
    return ~small
