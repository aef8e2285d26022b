"""Views: one stereo reconstruction (or one point cloud) with its rig and pose.

A view's points are in its *rig frame* (the world frame of its rig file, where
:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair` puts them); its
pose ``T`` (4x4) maps them to the common world frame. Views of one fusion must
all share one world unit. Reading a view from a folder on disk (and
reconstructing it) is :func:`canopy_stereo.pipeline.views.load_view`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.errors import UnitMismatchError
from canopy_stereo.geometry.clouds import check_cloud
from canopy_stereo.geometry.transforms import check_transform, transform_points


@dataclass
class View:
    """One view of the plant.

    Attributes:
        name: view name (its folder name on disk).
        points: (N, 3) float64 points in the view's rig frame, world units.
        colors: (N, 3) uint8 RGB or None.
        unit: world unit (``"mm"``, ``"m"``, ...).
        pose: (4, 4) rig frame -> world, or None when unknown (to be registered).
        P_left: (3, 4) left camera of the rig (rig frame -> pixels), or None.
        image_size: ``(width, height)`` of the left image, or None.
        image: (H, W, 3) uint8 BGR left image, or None.
        organized: (H, W, 3) rig-frame points of the left pixels (NaN where none), or None.
        source: where the view came from (for messages).
    """

    name: str
    points: np.ndarray
    colors: np.ndarray | None
    unit: str
    pose: np.ndarray | None = None
    P_left: np.ndarray | None = None
    image_size: tuple | None = None
    image: np.ndarray | None = None
    organized: np.ndarray | None = None
    source: str = ""

    def __post_init__(self):
        pts = check_cloud(self.points, organized=None, name=f"points of view {self.name!r}").reshape(-1, 3)
        keep = np.all(np.isfinite(pts), axis=1)
        self.points = pts[keep]
        if self.colors is not None:
            cols = np.asarray(self.colors).reshape(-1, 3)
            if len(cols) != len(keep):
                raise CanopyStereoError(f"view {self.name!r}: {len(cols)} colours for {len(keep)} points")
            self.colors = cols[keep].astype(np.uint8)
        if self.pose is not None:
            self.pose = check_transform(self.pose, f"pose of view {self.name!r}")

    @property
    def has_image(self) -> bool:
        """True when the view has a left image and its organized cloud (feature registration)."""
        return self.image is not None and self.organized is not None

    @property
    def camera_centre(self) -> np.ndarray | None:
        """Left camera centre (3,) in the rig frame, or None without a camera."""
        if self.P_left is None:
            return None
        from canopy_stereo.geometry.camera import camera_centre

        return camera_centre(self.P_left)

    def world_points(self, pose=None) -> np.ndarray:
        """Points in the world frame with ``pose`` (default: the view's own)."""
        T = self.pose if pose is None else pose
        if T is None:
            raise CanopyStereoError(f"view {self.name!r} has no pose")
        return transform_points(T, self.points)


def far_point_mask(points, P_left, *, max_depth_factor: float = 5.0) -> np.ndarray:
    """(N,) bool: points deeper than ``max_depth_factor`` x the median depth in camera ``P_left``.

    Near-zero disparities triangulate to points kilometres away; they are no
    part of a plant a metre from the rig and would only stretch the voxel grid.
    """
    from canopy_stereo.geometry.camera import point_depth

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros(0, bool)
    z = point_depth(P_left, pts)
    return z > max_depth_factor * np.median(z)


def view_from_reconstruction(name: str, rec, rig, left_bgr, *, pose=None, source: str = "",
                             max_depth_factor: float = 5.0) -> View:
    """A :class:`View` from a :class:`~canopy_stereo.pipeline.reconstruct.Reconstruction`.

    Points deeper than ``max_depth_factor`` x the median depth (degenerate
    near-zero disparities) are dropped, here and in the organized cloud.
    """
    organized = np.array(rec.organized, np.float64, copy=True)
    far = far_point_mask(rec.points, rig.P_left, max_depth_factor=max_depth_factor)
    if np.any(far):
        uv = np.asarray(rec.pixels)[far]
        organized[uv[:, 1], uv[:, 0]] = np.nan
    return View(name=name, points=rec.points[~far], colors=rec.colors[~far], unit=rig.world_unit,
                pose=pose, P_left=rig.P_left, image_size=rig.image_size, image=np.asarray(left_bgr),
                organized=organized, source=source)


def common_unit(views, poses_unit: str | None = None) -> str:
    """The one unit of all views (and of a pose file); raises :class:`UnitMismatchError` otherwise."""
    if not views:
        raise CanopyStereoError("no views given")
    units = {v.unit for v in views}
    if len(units) > 1:
        listing = ", ".join(f"{v.name}: {v.unit}" for v in views)
        raise UnitMismatchError(f"views are in different units ({listing}); reconstruct them with rigs "
                                "in one world unit")
    unit = units.pop()
    if poses_unit is not None and poses_unit != unit:
        raise UnitMismatchError(f"the pose file is in {poses_unit} but the views are in {unit}")
    return unit
