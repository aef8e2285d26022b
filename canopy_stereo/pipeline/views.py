"""A view folder on disk -> a :class:`~canopy_stereo.fusion.views.View` (reconstructed when it is a pair).

A view on disk (one folder, its name is the view's name) is either

* a stereo pair: ``left.png``, ``right.png`` (or ``.jpg``, ``.bmp``, ``.tif``)
  and ``rig.yaml``; optional ``mask.png`` (foreground on the left image) and
  ``pose.yaml``. It is reconstructed on loading
  (:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`), and keeps its left
  image and organized cloud so views can be registered by feature matching; or
* a point cloud: ``cloud.ply`` (rig-frame points, e.g. written by
  ``canopy-stereo reconstruct``) with optional ``pose.yaml`` and optional
  ``rig.yaml`` (its left camera lets fusion test free space against this view).

The unit comes from the rig file (``world_unit``), the PLY (``comment unit``)
or ``pose.yaml``; views of one fusion must all share it.
"""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.errors import UnitMismatchError
from canopy_stereo.fusion.views import View, view_from_reconstruction

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


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
