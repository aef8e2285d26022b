"""Voxel fusion of registered views into one coloured cloud with view counts.

All views' points (world frame) are binned into cubic voxels of edge
``voxel``; each occupied voxel becomes one point at the mean of its points,
with their mean colour, the number of points merged and the number of views
that saw it. A view *sees* a voxel when it has a point in the voxel or in one
of its 26 neighbours, so the same surface reconstructed by two views with
depth noise of about a voxel counts both views even when their points fall
into adjacent voxels.

Averaging across views: each view's depth noise (a few millimetres for the
paper's rig at 600-700 mm) scatters one surface over a shell thicker than a
voxel, so voxel means alone would keep several layers. Every voxel mean is
therefore moved along the normal onto the plane of its neighbours (all views
together, weighted by their point counts) before a second binning merges the
voxels that now coincide: overlapping views are averaged into one surface,
which is what a TSDF's zero crossing achieves, without a volume.

Outliers: a voxel seen by only one view is dropped when another view with a
camera sees through it (:mod:`canopy_stereo.fusion.freespace`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.freespace import DepthView
from canopy_stereo.fusion.voxel import dilate_keys, group_by_key, voxel_keys


@dataclass
class FusedCloud:
    """The fused model.

    Attributes:
        points: (M, 3) float64 voxel means, world units.
        colors: (M, 3) uint8 RGB mean colours, or None when no view had colours.
        view_count: (M,) int number of views that saw each point.
        point_count: (M,) int number of input points merged into each point.
        unit: world unit.
        voxel: voxel edge, world units.
        removed_free_space: voxels dropped because another view saw through them.
        stats: further figures (points per view, ...).
    """

    points: np.ndarray
    colors: np.ndarray | None
    view_count: np.ndarray
    point_count: np.ndarray
    unit: str
    voxel: float
    removed_free_space: int = 0
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.points)

    def subset(self, keep) -> FusedCloud:
        """The points selected by the mask or indices ``keep``."""
        return FusedCloud(points=self.points[keep], view_count=self.view_count[keep],
                          colors=None if self.colors is None else self.colors[keep],
                          point_count=self.point_count[keep], unit=self.unit, voxel=self.voxel,
                          removed_free_space=self.removed_free_space, stats=dict(self.stats))


def _weighted_sums(inv, weights, values):
    """Per-group sums of ``weights * values`` (values (N, C)) for group indices ``inv``."""
    return np.stack([np.bincount(inv, weights=weights * values[:, a]) for a in range(values.shape[1])], axis=1)


def surface_average(points, weights, radius: float, *, k: int = 24, min_neighbours: int = 6):
    """Move each point onto the plane fitted to its neighbours within ``radius``.

    The plane is the weighted least-squares plane of the (at most ``k``)
    neighbours; only the offset along its normal changes, so the points of
    several views of one surface, scattered across it by their depth noise,
    collapse onto a common surface while keeping their spread along it.
    Points with fewer than ``min_neighbours`` neighbours stay where they are.

    Args:
        points: (M, 3) points, world units.
        weights: (M,) non-negative weights (e.g. points merged into each).
        radius: neighbourhood radius, world units.

    Returns:
        (M, 3) moved points.
    """
    from scipy.spatial import cKDTree

    pts = np.asarray(points, np.float64)
    w = np.asarray(weights, np.float64)
    if len(pts) < min_neighbours:
        return pts.copy()
    k = int(min(k, len(pts)))
    dist, idx = cKDTree(pts).query(pts, k=k, distance_upper_bound=radius)
    found = np.isfinite(dist)
    idx = np.where(found, idx, 0)
    nw = np.where(found, w[idx], 0.0)                     # (M, k)
    wsum = nw.sum(axis=1)
    nb = pts[idx]
    centre = np.einsum("mk,mki->mi", nw, nb) / np.maximum(wsum, 1e-300)[:, None]
    d = nb - centre[:, None, :]
    cov = np.einsum("mk,mki,mkj->mij", nw, d, d) / np.maximum(wsum, 1e-300)[:, None, None]
    normal = np.linalg.eigh(cov)[1][:, :, 0]
    offset = np.einsum("mi,mi->m", pts - centre, normal)
    move = found.sum(axis=1) >= min_neighbours
    out = pts.copy()
    out[move] -= offset[move, None] * normal[move]
    return out


def fuse_point_sets(point_sets, voxel: float, unit: str, *, depth_views=None, free_space: bool = True,
                    margin_abs: float | None = None, margin_rel: float = 0.02,
                    min_views: int = 1, average_radius: float | None = None) -> FusedCloud:
    """Fuse world-frame point sets (one per view) into a :class:`FusedCloud`.

    Steps: bin all points into voxels (means of position and colour, point
    counts, the views that saw each voxel or its 26 neighbours); drop
    single-view voxels that another view sees through; move every voxel mean
    onto the plane of its neighbours within ``average_radius`` (so the depth
    noise of the views, which scatters one surface over a shell a few voxels
    thick, is averaged across views); bin the moved means again, merging
    voxels that now coincide.

    Args:
        point_sets: list of ``(points (N, 3), colours (N, 3) uint8 or None)`` in the world frame.
        voxel: voxel edge, world units.
        unit: world unit of the points.
        depth_views: optional list (same length) of :class:`DepthView` or None,
            the views' cameras and depth images for the free-space test.
        free_space: drop single-view voxels that another view sees through.
        margin_abs, margin_rel: a view sees through a point when its observed
            depth exceeds the point's by more than ``max(margin_abs, margin_rel * depth)``;
            ``margin_abs`` defaults to 3 voxels.
        min_views: keep only voxels seen by at least this many views.
        average_radius: neighbourhood of the surface averaging, world units
            (default 2.5 voxels; 0 turns it off).
    """
    if not voxel > 0:
        raise CanopyStereoError(f"voxel size must be positive, got {voxel}")
    if not point_sets:
        raise CanopyStereoError("nothing to fuse: no views")
    n_views = len(point_sets)
    pts_list, col_list, key_list = [], [], []
    with_colors = all(c is not None for _, c in point_sets)
    for pts, cols in point_sets:
        pts = np.asarray(pts, np.float64).reshape(-1, 3)
        ok = np.all(np.isfinite(pts), axis=1)
        pts_list.append(pts[ok])
        if with_colors:
            col_list.append(np.asarray(cols).reshape(-1, 3)[ok])
        key_list.append(voxel_keys(pts[ok], voxel))
    all_pts = np.concatenate(pts_list)
    if len(all_pts) == 0:
        raise CanopyStereoError("nothing to fuse: the views have no points")
    keys, inv = group_by_key(np.concatenate(key_list))
    counts = np.bincount(inv).astype(np.float64)
    ones = np.ones(len(all_pts))
    means = _weighted_sums(inv, ones, all_pts) / counts[:, None]
    colors = None
    if with_colors:
        colors = _weighted_sums(inv, ones, np.concatenate(col_list).astype(np.float64)) / counts[:, None]

    seen = np.zeros((len(keys), n_views), bool)   # view k has a point within the 3x3x3 block
    for k, kk in enumerate(key_list):
        if len(kk):
            seen[:, k] = np.isin(keys, dilate_keys(kk), assume_unique=True)

    removed = 0
    if free_space and depth_views is not None:
        if len(depth_views) != n_views:
            raise CanopyStereoError(f"{len(depth_views)} depth views for {n_views} point sets")
        margin = 3.0 * voxel if margin_abs is None else float(margin_abs)
        single = np.nonzero(seen.sum(axis=1) == 1)[0]
        owner = np.argmax(seen[single], axis=1)
        votes = np.zeros(len(single), np.int64)
        for j, dv in enumerate(depth_views):
            if dv is None:
                continue
            others = owner != j
            hit = dv.seen_through(means[single[others]], margin, margin_rel)
            votes[np.nonzero(others)[0][hit]] += 1
        keep = np.ones(len(keys), bool)
        keep[single[votes > 0]] = False
        removed = int((~keep).sum())
        means, counts, seen = means[keep], counts[keep], seen[keep]
        colors = None if colors is None else colors[keep]

    radius = 2.5 * voxel if average_radius is None else float(average_radius)
    if radius > 0 and len(means):
        moved = surface_average(means, counts, radius)
        _, inv2 = group_by_key(voxel_keys(moved, voxel))
        merged_counts = np.bincount(inv2, weights=counts)
        means = _weighted_sums(inv2, counts, moved) / merged_counts[:, None]
        if colors is not None:
            colors = _weighted_sums(inv2, counts, colors) / merged_counts[:, None]
        seen = np.stack([np.bincount(inv2, weights=seen[:, k]) > 0 for k in range(n_views)], axis=1)
        counts = merged_counts
    view_count = seen.sum(axis=1)
    if colors is not None:
        colors = np.clip(np.rint(colors), 0, 255).astype(np.uint8)
    if min_views > 1:
        keep = view_count >= min_views
        means, counts, view_count = means[keep], counts[keep], view_count[keep]
        colors = None if colors is None else colors[keep]
    stats = {"input_points": int(len(all_pts)), "points_per_view": [int(len(p)) for p in pts_list],
             "voxels": int(len(keys))}
    return FusedCloud(points=means, colors=colors, view_count=view_count.astype(np.int64),
                      point_count=np.rint(counts).astype(np.int64), unit=unit, voxel=float(voxel),
                      removed_free_space=removed, stats=stats)


def depth_view_of(view, pose) -> DepthView | None:
    """The :class:`DepthView` of a :class:`~canopy_stereo.fusion.views.View` at ``pose``
    (None for a view without a camera)."""
    if view.P_left is None:
        return None
    if view.organized is not None:
        return DepthView.from_organized(view.P_left, view.organized, pose)
    if view.image_size is None:
        return None
    return DepthView.from_points(view.P_left, view.points, view.image_size, pose)


def fuse_views(views, poses=None, *, voxel: float = 2.0, free_space: bool = True,
               margin_abs: float | None = None,
               margin_rel: float = 0.02, min_views: int = 1, average_radius: float | None = None) -> FusedCloud:
    """Fuse :class:`~canopy_stereo.fusion.views.View` objects at their poses.

    Args:
        views: the views (one unit).
        poses: list of (4, 4) rig -> world poses; default: each view's ``pose``.
        voxel, free_space, margin_abs, margin_rel, min_views, average_radius: see
            :func:`fuse_point_sets`.
    """
    from canopy_stereo.fusion.views import common_unit

    unit = common_unit(views)
    if poses is None:
        missing = [v.name for v in views if v.pose is None]
        if missing:
            raise CanopyStereoError(f"view(s) {', '.join(missing)} have no pose; register them first")
        poses = [v.pose for v in views]
    sets = [(v.world_points(T), v.colors) for v, T in zip(views, poses)]
    depth_views = [depth_view_of(v, T) for v, T in zip(views, poses)] if free_space else None
    return fuse_point_sets(sets, voxel, unit, depth_views=depth_views, free_space=free_space,
                           margin_abs=margin_abs, margin_rel=margin_rel, min_views=min_views,
                           average_radius=average_radius)
