"""Incremental fusion of a stream of clouds (the ROS ``fusion_node``'s core).

Clouds arrive one at a time in the rig frame, each with a pose (from a
turntable, the robot's pose topic) or without one. A cloud without a pose is
registered onto the previous cloud by robust point-to-plane ICP starting from
the previous pose (a stream's consecutive clouds are close), and rejected with
:class:`~canopy_stereo.fusion.errors.RegistrationError` when it does not
overlap. Each accepted cloud is kept down-sampled to the fusion voxel; the
fused model is recomputed from all kept clouds on request (a stream is fused
at a lower rate than clouds arrive).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.freespace import DepthView
from canopy_stereo.fusion.fuse import FusedCloud, fuse_point_sets
from canopy_stereo.fusion.registration import RegistrationSettings, _Prepared, _register
from canopy_stereo.fusion.views import View
from canopy_stereo.fusion.voxel import voxel_downsample
from canopy_stereo.geometry.clouds import check_cloud
from canopy_stereo.geometry.transforms import check_transform, transform_points


@dataclass
class AddResult:
    """What :meth:`IncrementalFusion.add` did with a cloud.

    Attributes:
        index: running number of the cloud.
        pose: (4, 4) rig -> world pose used.
        registered: True when the pose came from ICP (no pose was given).
        rmse: ICP residual (world units), or NaN when the pose was given.
        overlap: share of the cloud within the ICP overlap radius of the previous one (NaN when given).
        points: points kept after down-sampling.
    """

    index: int
    pose: np.ndarray
    registered: bool
    rmse: float
    overlap: float
    points: int


@dataclass
class _Kept:
    points: np.ndarray
    colors: np.ndarray | None
    pose: np.ndarray
    depth_view: DepthView | None


class IncrementalFusion:
    """Fuse clouds as they come.

    Args:
        voxel: fusion voxel, world units.
        unit: world unit of the clouds and poses.
        settings: registration settings for clouds without a pose (voxel
            defaults to 1.5 fusion voxels).
        max_views: keep at most this many clouds (oldest dropped); 0 = all.
        free_space: drop single-view voxels that another view sees through
            (only clouds given with a camera take part).
        min_views: publish only voxels seen by at least this many views.
    """

    def __init__(self, voxel: float, unit: str = "m", settings: RegistrationSettings | None = None,
                 max_views: int = 0, free_space: bool = True, min_views: int = 1):
        if not voxel > 0:
            raise CanopyStereoError(f"fusion voxel must be positive, got {voxel}")
        self.voxel = float(voxel)
        self.unit = unit
        self.settings = settings or RegistrationSettings(voxel=1.5 * self.voxel)
        self.max_views = int(max_views)
        self.free_space = bool(free_space)
        self.min_views = int(min_views)
        self.reset()

    def reset(self) -> None:
        """Forget every cloud (the world frame is re-anchored by the next one)."""
        self._kept: list[_Kept] = []
        self._previous: _Prepared | None = None
        self._previous_pose: np.ndarray | None = None
        self._count = 0

    @property
    def view_count(self) -> int:
        """Number of clouds currently fused."""
        return len(self._kept)

    def add(self, points, colors=None, *, pose=None, P_left=None, image_size=None) -> AddResult:
        """Add one rig-frame cloud.

        Args:
            points: (N, 3) or (H, W, 3) rig-frame points (NaN rows ignored).
            colors: matching uint8 RGB, or None.
            pose: (4, 4) rig -> world, or None to register onto the previous cloud
                (the first cloud without a pose defines the world frame).
            P_left, image_size: the rig's left camera (rig frame -> pixels, in this
                unit) and image size, to take part in the free-space test.

        Raises:
            RegistrationError: no pose and the cloud does not overlap the previous one.
            CanopyStereoError: a malformed pose or too few points.
        """
        pts = check_cloud(points, organized=None, name="points").reshape(-1, 3)
        cols = None if colors is None else np.asarray(colors).reshape(-1, 3)
        ok = np.all(np.isfinite(pts), axis=1)
        pts = pts[ok]
        cols = None if cols is None else cols[ok]
        if len(pts) < 30:
            raise CanopyStereoError(f"cloud has only {len(pts)} valid points")
        view = View(name=f"cloud_{self._count}", points=pts, colors=cols, unit=self.unit, P_left=P_left,
                    image_size=image_size)
        settings = self.settings.resolved()
        prepared = _Prepared(view, settings)
        rmse = overlap = float("nan")
        registered = False
        if pose is not None:
            T = check_transform(pose, "cloud pose")
        elif self._previous is None:
            T = np.eye(4)
        else:
            pair = _register(self._previous, prepared, settings, T_init=np.eye(4))
            T = self._previous_pose @ pair.transform
            rmse, overlap, registered = pair.icp.rmse, pair.icp.overlap, True
        kept_pts, kept_cols, _ = voxel_downsample(pts, self.voxel, colors=cols)
        dv = None
        if P_left is not None and image_size is not None:
            dv = DepthView.from_points(P_left, pts, image_size, T)
        self._kept.append(_Kept(kept_pts, kept_cols, T, dv))
        if self.max_views and len(self._kept) > self.max_views:
            self._kept.pop(0)
        self._previous, self._previous_pose = prepared, T
        self._count += 1
        return AddResult(index=self._count - 1, pose=T, registered=registered, rmse=rmse, overlap=overlap,
                         points=int(len(kept_pts)))

    def fused(self) -> FusedCloud:
        """The fused model of the kept clouds (world frame)."""
        if not self._kept:
            raise CanopyStereoError("nothing fused yet: no cloud was added")
        sets = [(transform_points(k.pose, k.points), k.colors) for k in self._kept]
        depth_views = [k.depth_view for k in self._kept]
        return fuse_point_sets(sets, self.voxel, self.unit, depth_views=depth_views,
                               free_space=self.free_space, min_views=self.min_views)
