"""Views: one stereo reconstruction (or one point cloud) with its rig and pose.

A view's points are in its *rig frame* (the world frame of its rig file, where
:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair` puts them); its
pose ``T`` (4x4) maps them to the common world frame.

A view on disk (one folder, its name is the view's name) is either

* a stereo pair: ``left.png``, ``right.png`` (or ``.jpg``, ``.bmp``, ``.tif``)
  and ``rig.yaml``; optional ``mask.png`` (foreground on the left image) and
  ``pose.yaml``. It is reconstructed on loading, and keeps its left image and
  organized cloud so views can be registered by feature matching; or
* a point cloud: ``cloud.ply`` (rig-frame points, e.g. written by
  ``canopy-stereo reconstruct``) with optional ``pose.yaml`` and optional
  ``rig.yaml`` (its left camera lets fusion test free space against this view).

The unit comes from the rig file (``world_unit``), the PLY (``comment unit``)
or ``pose.yaml``; views of one fusion must all share it.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.errors import UnitMismatchError
from canopy_stereo.fusion.transforms import check_transform, transform_points

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


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
        pts = np.asarray(self.points, np.float64).reshape(-1, 3)
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


def _find_image(folder: Path, stem: str) -> Path | None:
    for ext in IMAGE_EXTENSIONS:
        for cand in (folder / f"{stem}{ext}", folder / f"{stem}{ext.upper()}"):
            if cand.is_file():
                return cand
    return None


def _find_rig(folder: Path) -> Path | None:
    for cand in (folder / "rig.yaml", folder / "rig.yml"):
        if cand.is_file():
            return cand
    return None


def _read_pose(folder: Path, name: str):
    path = folder / "pose.yaml"
    if not path.is_file():
        return None, None
    from canopy_stereo.fusion.poses import read_poses

    ps = read_poses(path)
    if len(ps.poses) != 1:
        raise CanopyStereoError(f"{path} must hold one pose ('pose: [16 numbers]'), found {len(ps.poses)}")
    return next(iter(ps.poses.values())), ps.unit


def load_view(folder, unit: str | None = None, *, method: str | None = None, matcher: str = "sgbm",
              matcher_params=None) -> View:
    """Load (and, for a stereo pair, reconstruct) the view stored in ``folder``.

    Args:
        folder: view folder (see the module docstring for its files).
        unit: unit to assume for a ``cloud.ply`` that names none.
        method, matcher, matcher_params: reconstruction settings for a stereo pair
            (``method`` None: the rig's rectification method, else Fusiello).

    Raises:
        CanopyStereoError: missing files, or a pose file whose unit differs from the view's.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CanopyStereoError(f"view {folder} is not a folder (expected left.png, right.png and "
                                "rig.yaml, or cloud.ply)")
    name = folder.resolve().name
    left_path, right_path = _find_image(folder, "left"), _find_image(folder, "right")
    rig_path = _find_rig(folder)
    pose, pose_unit = _read_pose(folder, name)
    if left_path and right_path and rig_path:
        from canopy_stereo.io.images import read_image
        from canopy_stereo.io.rig import load_rig
        from canopy_stereo.pipeline.reconstruct import reconstruct_pair

        rig = load_rig(rig_path)
        left, right = read_image(left_path), read_image(right_path)
        mask_path = _find_image(folder, "mask")
        mask = read_image(mask_path, color=False) if mask_path else None
        rec = reconstruct_pair(left, right, rig, method=method, matcher=matcher, mask=mask,
                               matcher_params=matcher_params)
        view = view_from_reconstruction(name, rec, rig, left, source=str(folder))
    elif (folder / "cloud.ply").is_file():
        from canopy_stereo.io.ply import read_ply

        cloud = read_ply(folder / "cloud.ply")
        rig = None
        if rig_path:
            from canopy_stereo.io.rig import load_rig

            rig = load_rig(rig_path)
        cloud_unit = cloud.unit or (rig.world_unit if rig else None) or pose_unit or unit
        if cloud_unit is None:
            raise UnitMismatchError(f"{folder / 'cloud.ply'} names no unit (no 'comment unit' line, no "
                                    "rig.yaml or pose.yaml beside it); give one with --unit")
        if rig is not None and rig.world_unit != cloud_unit:
            raise UnitMismatchError(f"view {name!r}: cloud.ply is in {cloud_unit} but rig.yaml in "
                                    f"{rig.world_unit}")
        view = View(name=name, points=cloud.points, colors=cloud.colors, unit=cloud_unit,
                    P_left=None if rig is None else rig.P_left,
                    image_size=None if rig is None else rig.image_size, source=str(folder))
    else:
        found = sorted(p.name for p in folder.iterdir())[:8]
        raise CanopyStereoError(f"view {folder} has neither a stereo pair (left.png, right.png, rig.yaml) "
                                f"nor cloud.ply; it holds {', '.join(found) or 'nothing'}")
    if pose is not None:
        if pose_unit != view.unit:
            raise UnitMismatchError(f"view {name!r}: pose.yaml is in {pose_unit} but the view is in {view.unit}")
        view.pose = pose
    if len(view.points) == 0:
        raise CanopyStereoError(f"view {name!r} has no 3-D points")
    return view


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
