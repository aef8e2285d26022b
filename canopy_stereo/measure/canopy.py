"""Canopy size: extents in the measuring frame, convex-hull and voxel volumes.

Canopy height, width and depth are the extents of the plant's points along
``z``, ``x`` and ``y`` of the measuring frame (:mod:`canopy_stereo.measure.frame`).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.measure.frame import MeasuringFrame


def nice_voxel_size(extent: float, cells: int = 50) -> float:
    """A round voxel edge (1, 2, 2.5 or 5 times a power of ten) near ``extent / cells``."""
    if not np.isfinite(extent) or extent <= 0:
        return 1.0
    raw = extent / cells
    p = 10.0 ** np.floor(np.log10(raw))
    candidates = np.array([1.0, 2.0, 2.5, 5.0, 10.0]) * p
    return float(candidates[np.argmin(np.abs(np.log(candidates / raw)))])


def voxel_volume(points: np.ndarray, voxel_size: float) -> tuple[float, int]:
    """Volume of the occupied cubic voxels of edge ``voxel_size`` and their count. The voxels are
    those of one fixed grid of the world frame (faces at multiples of ``voxel_size``), not of a
    grid hung on the lowest point: the last digits of one point can then move it to the next
    voxel at most, never shift the whole grid (entry points whose clouds differ in the last
    digits count the same voxels)."""
    if voxel_size <= 0 or not np.isfinite(voxel_size):
        raise CanopyStereoError(f"voxel size must be positive, got {voxel_size}")
    P = np.asarray(points, np.float64)
    if not len(P):
        return 0.0, 0
    idx = np.floor(P / voxel_size).astype(np.int64)
    n = len(np.unique(idx, axis=0))
    return float(n * voxel_size ** 3), int(n)


def hull_volume(points: np.ndarray) -> float:
    """Convex-hull volume (world units cubed); 0 for flat or tiny point sets."""
    from scipy.spatial import ConvexHull, QhullError

    P = np.asarray(points, np.float64)
    if len(P) < 4:
        return 0.0
    if len(P) > 200000:
        P = P[np.random.default_rng(0).choice(len(P), 200000, replace=False)]
    try:
        return float(ConvexHull(P).volume)
    except (QhullError, ValueError):
        return 0.0


def canopy_dimensions(points: np.ndarray, frame: MeasuringFrame, *, voxel_size: float | None = None,
                      leaf_area: float | None = None) -> dict:
    """Extents, volumes and leaf-area density of canopy points (N, 3) in ``frame``.

    Returns a dict with ``height``, ``width``, ``depth`` (extents along z, x,
    y), ``top_above_ground``/``base_above_ground`` (with a ground plane),
    ``hull_volume``, ``voxel_volume``, ``voxel_size``, ``occupied_voxels``,
    ``leaf_area``, ``leaf_area_density`` (leaf area / hull volume, 1/unit),
    ``bbox_min``/``bbox_max`` (frame coordinates) and ``n_points``.
    """
    P = np.asarray(points, np.float64)
    if len(P) < 3:
        raise CanopyStereoError(f"the canopy has {len(P)} 3D points; need at least 3 to measure it")
    F = frame.to_frame(P)
    lo, hi = F.min(axis=0), F.max(axis=0)
    ext = hi - lo
    if voxel_size is None:
        voxel_size = nice_voxel_size(float(ext.max()))
    vvol, nvox = voxel_volume(P, voxel_size)
    hvol = hull_volume(P)
    out = {
        "height": float(ext[2]),
        "width": float(ext[0]),
        "depth": float(ext[1]),
        "top_above_ground": float(hi[2]) if frame.ground_plane is not None else None,
        "base_above_ground": float(lo[2]) if frame.ground_plane is not None else None,
        "hull_volume": hvol,
        "voxel_volume": vvol,
        "voxel_size": float(voxel_size),
        "occupied_voxels": nvox,
        "leaf_area": None if leaf_area is None else float(leaf_area),
        "leaf_area_density": (float(leaf_area) / hvol) if (leaf_area is not None and hvol > 0) else None,
        "bbox_min": [float(v) for v in lo],
        "bbox_max": [float(v) for v in hi],
        "centroid": [float(v) for v in P.mean(axis=0)],
        "n_points": int(len(P)),
    }
    return out
