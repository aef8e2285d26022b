"""The measuring frame of canopy extents: ground plane, up, across and away from the camera.

The measuring frame has its ``z`` axis up, ``x`` across the view (image right
projected onto the horizontal) and ``y`` away from the camera (horizontal
depth), right-handed. "Up" is the normal of the ground plane when one is found
(planes peeled off the non-plant points by RANSAC, keeping one within 35
degrees of the image's up direction: floors, table tops, soil, not backdrops),
else the image's up direction (:func:`measuring_frame`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import decompose_projection
from canopy_stereo.measure.surface import local_linear_fit

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


def image_directions(organized, valid, camera):
    """World directions of image right, image down and the view, from the camera or the grid."""
    if camera is not None:
        R = decompose_projection(camera).R
        return R[0].copy(), R[1].copy(), R[2].copy()
    _, Xu, Xv = local_linear_fit(organized, valid, valid, sigma=2.0)
    ok = valid & np.all(np.isfinite(Xu), -1) & np.all(np.isfinite(Xv), -1)
    if ok.sum() < 3:
        return np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        right = np.nanmean(Xu[ok] / np.linalg.norm(Xu[ok], axis=1, keepdims=True), axis=0)
        down = np.nanmean(Xv[ok] / np.linalg.norm(Xv[ok], axis=1, keepdims=True), axis=0)
    right /= np.linalg.norm(right)
    down = down - (down @ right) * right
    down /= np.linalg.norm(down)
    return right, down, np.cross(right, down)


def measuring_frame(canopy: np.ndarray, background: np.ndarray, ground, right, down, view,
                    scale: float, *, seed: int = 0) -> MeasuringFrame:
    """The frame for canopy extents.

    Args:
        canopy, background: (N, 3) plant points and other points (ground candidates).
        ground: ``"auto"`` (fit a ground plane, else image up), ``"camera"``
            (image up), ``"view"`` (up = towards the camera: top views) or a
            plane ``(a, b, c, d)``, ``a x + b y + c z + d = 0``, whose normal
            side holding most of the canopy is up.
        right, down, view: world directions of the image axes and the view.
        scale: typical distance to the scene (sets the RANSAC threshold, 1 %).
    """
    centre = canopy.mean(axis=0)
    if isinstance(ground, str):
        if ground in ("camera", "none"):
            return MeasuringFrame(centre, frame_from_up(-down, right, centre), "camera")
        if ground == "view":
            return MeasuringFrame(centre, frame_from_up(-view, right, centre), "view")
        if ground != "auto":
            raise CanopyStereoError(
                f"ground must be 'auto', 'camera', 'view' or a plane a,b,c,d; got {ground!r}")
        found = find_ground(background, canopy, -down, threshold=0.01 * scale, seed=seed)
        if found is None:
            return MeasuringFrame(centre, frame_from_up(-down, right, centre), "camera")
        n, d, count = found
        kind = "ground"
    else:
        try:
            plane = np.asarray(ground, np.float64).ravel()
        except (TypeError, ValueError):
            raise CanopyStereoError(f"ground plane must be 4 numbers a,b,c,d; got {ground!r}") from None
        if plane.size != 4 or not np.all(np.isfinite(plane)) or np.linalg.norm(plane[:3]) == 0:
            raise CanopyStereoError(f"ground plane must be 4 finite numbers a,b,c,d with (a,b,c) != 0; "
                                    f"got {ground!r}")
        norm = np.linalg.norm(plane[:3])
        n, d = plane[:3] / norm, plane[3] / norm
        if np.median(canopy @ n + d) < 0:
            n, d = -n, -d
        count, kind = 0, "plane"
    foot = centre - (centre @ n + d) * n
    return MeasuringFrame(foot, frame_from_up(n, right, foot), kind,
                          ground_plane=np.append(n, d), ground_inliers=count)
