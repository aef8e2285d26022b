"""Canopy size: a measuring frame, extents, convex-hull and voxel volumes.

The measuring frame has its ``z`` axis up, ``x`` across the view (image right
projected onto the horizontal) and ``y`` away from the camera (horizontal
depth), right-handed. "Up" is the normal of the ground plane when one is found
(planes peeled off the non-plant points by RANSAC, keeping one within 35
degrees of the image's up direction: floors, table tops, soil, not backdrops),
else the image's up direction. Canopy height, width and depth are the extents
of the plant's points along ``z``, ``x`` and ``y``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Largest angle (degrees) between a ground plane's normal and the image's up direction.
GROUND_MAX_TILT_DEG = 35.0


@dataclass
class MeasuringFrame:
    """Orthonormal frame for canopy extents.

    Attributes:
        origin: (3,) world point (on the ground plane when there is one).
        axes: (3, 3) rows ``x`` (across, width), ``y`` (away from the camera,
            depth), ``z`` (up, height) as world unit vectors.
        kind: ``"ground"`` (fitted ground plane), ``"plane"`` (given plane),
            ``"camera"`` (image up) or ``"view"`` (up = towards the camera, for top views).
        ground_plane: ``(a, b, c, d)`` with ``a x + b y + c z + d = 0``,
            ``(a, b, c)`` the unit up normal, or None.
        ground_inliers: points that supported the ground plane (0 if none).
    """

    origin: np.ndarray
    axes: np.ndarray
    kind: str
    ground_plane: np.ndarray | None = None
    ground_inliers: int = 0

    def to_frame(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) frame coordinates ``(x, y, z)`` of world points (N, 3)."""
        return (np.asarray(points, np.float64) - self.origin) @ self.axes.T

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "origin": [float(v) for v in self.origin],
            "x_axis": [float(v) for v in self.axes[0]],
            "y_axis": [float(v) for v in self.axes[1]],
            "z_axis": [float(v) for v in self.axes[2]],
            "ground_plane": None if self.ground_plane is None else [float(v) for v in self.ground_plane],
            "ground_inliers": int(self.ground_inliers),
        }


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def frame_from_up(up, right_hint, origin) -> np.ndarray:
    """(3, 3) axes rows x, y, z from an up direction and a rough 'right' direction."""
    z = _unit(up)
    r = np.asarray(right_hint, np.float64) - (np.asarray(right_hint, np.float64) @ z) * z
    if np.linalg.norm(r) < 1e-9:  # looking straight along up: any horizontal direction
        r = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x = _unit(r)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def ransac_plane(points: np.ndarray, threshold: float, *, iterations: int = 200, seed: int = 0,
                 normal_hint=None, max_tilt_deg: float | None = None):
    """Plane with the most points within ``threshold`` (world units), refined by least squares.

    Args:
        points: (N, 3) world points.
        threshold: inlier distance.
        iterations: random 3-point samples.
        seed: random seed (deterministic results).
        normal_hint, max_tilt_deg: only accept planes whose normal is within
            ``max_tilt_deg`` of ``normal_hint`` (either sign).

    Returns:
        ``(normal, d, inliers)`` with ``normal . X + d = 0`` and a bool (N,)
        inlier mask, or None when no acceptable plane has 3 inliers.
    """
    P = np.asarray(points, np.float64)
    n_pts = len(P)
    if n_pts < 3:
        return None
    rng = np.random.default_rng(seed)
    hint = None if normal_hint is None else _unit(normal_hint)
    min_cos = None if max_tilt_deg is None else np.cos(np.deg2rad(max_tilt_deg))
    best_count, best = 2, None
    sample = P if n_pts <= 5000 else P[rng.choice(n_pts, 5000, replace=False)]
    for _ in range(iterations):
        a, b, c = sample[rng.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        if hint is not None and abs(n @ hint) < min_cos:
            continue
        count = int(np.sum(np.abs((sample - a) @ n) <= threshold))
        if count > best_count:
            best_count, best = count, (n, -float(n @ a))
    if best is None:
        return None
    n, d = best
    for _ in range(3):  # least-squares refinement on the inliers
        inl = np.abs(P @ n + d) <= threshold
        if inl.sum() < 3:
            break
        c = P[inl].mean(axis=0)
        _, _, vt = np.linalg.svd(P[inl] - c, full_matrices=False)
        n_new = vt[2]
        if n_new @ n < 0:
            n_new = -n_new
        if hint is not None and abs(n_new @ hint) < min_cos:
            break
        n, d = n_new, -float(n_new @ c)
    inl = np.abs(P @ n + d) <= threshold
    return n, d, inl


def find_ground(background: np.ndarray, plant: np.ndarray, up_hint, threshold: float,
                *, min_inliers: int = 200, max_planes: int = 4, seed: int = 0):
    """Ground plane among ``background`` points, or None.

    The dominant planes are peeled off one after another (a backdrop first,
    then a table, a floor, the soil of a pot); the ground is the best-supported
    one with at least ``min_inliers`` points, a normal within
    :data:`GROUND_MAX_TILT_DEG` of ``up_hint`` and most of the ``plant``
    points that are not on it above it. Returns ``(up_normal, d, n_inliers)``.
    """
    up_hint = np.asarray(up_hint, np.float64)
    rest = np.asarray(background, np.float64)
    min_cos = np.cos(np.deg2rad(GROUND_MAX_TILT_DEG))
    best = None
    for k in range(max_planes):
        if len(rest) < max(min_inliers, 3):
            break
        found = ransac_plane(rest, threshold, seed=seed + k)
        if found is None:
            break
        n, d, inl = found
        count = int(inl.sum())
        if count < min_inliers:
            break
        if n @ up_hint < 0:
            n, d = -n, -d
        tilt_ok = n @ up_hint >= min_cos * np.linalg.norm(up_hint)
        h = plant @ n + d if len(plant) else np.zeros(0)
        off = h[np.abs(h) > threshold]  # plant points not lying on the plane itself
        above_ok = not len(off) or np.median(off) > 0
        if tilt_ok and above_ok and (best is None or count > best[2]):
            best = (n, d, count)
        rest = rest[~inl]
    return best


def nice_voxel_size(extent: float, cells: int = 50) -> float:
    """A round voxel edge (1, 2, 2.5 or 5 times a power of ten) near ``extent / cells``."""
    if not np.isfinite(extent) or extent <= 0:
        return 1.0
    raw = extent / cells
    p = 10.0 ** np.floor(np.log10(raw))
    candidates = np.array([1.0, 2.0, 2.5, 5.0, 10.0]) * p
    return float(candidates[np.argmin(np.abs(np.log(candidates / raw)))])


def voxel_volume(points: np.ndarray, voxel_size: float) -> tuple[float, int]:
    """Volume of the occupied cubic voxels of edge ``voxel_size`` and their count."""
    if voxel_size <= 0 or not np.isfinite(voxel_size):
        raise CanopyStereoError(f"voxel size must be positive, got {voxel_size}")
    P = np.asarray(points, np.float64)
    if not len(P):
        return 0.0, 0
    idx = np.floor((P - P.min(axis=0)) / voxel_size).astype(np.int64)
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
