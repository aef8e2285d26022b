"""Pose files: where each view's rig stood in the common world frame.

A view's pose ``T`` (4x4) maps points of the view's rig frame (the world frame
of its rig file, in which :func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`
returns its cloud) to the common world frame: ``x_world = T x_rig``.

``poses.yaml`` (several views, for ``canopy-stereo fuse --poses``)::

    unit: mm                    # unit of the translations (must match the views)
    poses:                      # view name (its folder name) -> 16 numbers, row-major 4x4
      view_00: [1, 0, 0, 0,   0, 1, 0, 0,   0, 0, 1, 0,   0, 0, 0, 1]
      view_01: [[0.707, 0, 0.707, -200], [0, 1, 0, 0], [-0.707, 0, 0.707, 59], [0, 0, 0, 1]]

A 4x4 nested list is accepted as well as 16 numbers. For a turntable the
poses may instead be given by angle: the plant turns by ``angle_deg``
(right-handed about ``axis_direction``) while the rig stands still, which is
the same as the rig turning by ``-angle_deg`` about that axis::

    unit: mm
    turntable:
      axis_point: [42.8, 0.0, 650.0]      # a point on the turntable axis (rig frame)
      axis_direction: [0.0, -1.0, 0.0]     # axis direction (rig frame), e.g. 'up'
      angles_deg: {view_00: 0, view_01: 45, view_02: 90}

Both sections may appear in one file (explicit matrices win). ``pose.yaml``
(one view, inside a view folder beside ``cloud.ply``) holds one matrix::

    unit: mm
    pose: [16 numbers, row-major]
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.transforms import check_transform, rotation_about_line
from canopy_stereo.io.rig import unit_to_metres
from canopy_stereo.io.yaml_files import read_yaml_file


@dataclass
class PoseSet:
    """Poses of named views.

    Attributes:
        unit: unit of the translations (``"mm"``, ``"m"``, ...).
        poses: view name -> (4, 4) rig frame -> world transform.
        source: where they were read from (for messages).
    """

    unit: str
    poses: dict = field(default_factory=dict)
    source: str = "poses"

    def __contains__(self, name) -> bool:
        return name in self.poses

    def __getitem__(self, name) -> np.ndarray:
        return self.poses[name]


def turntable_pose(angle_deg: float, axis_point, axis_direction) -> np.ndarray:
    """Rig pose (4, 4) of a view taken with the plant turned by ``angle_deg``.

    The turntable turns the plant by ``angle_deg`` (right-handed about
    ``axis_direction`` through ``axis_point``, both in the rig frame) while the
    rig stands still; the world frame is the plant at angle 0, so the rig's
    pose is the opposite rotation.
    """
    return rotation_about_line(axis_point, axis_direction, -np.radians(float(angle_deg)))


def _read_yaml(path: Path) -> dict:
    doc = read_yaml_file(path, "pose file")
    if not isinstance(doc, dict):
        raise CanopyStereoError(f"pose file {path} must be a mapping with 'unit' and 'poses' or 'pose'")
    return doc


def _unit_of(doc: dict, path) -> str:
    if "unit" not in doc:
        raise CanopyStereoError(f"pose file {path} has no 'unit' (e.g. 'unit: mm')")
    unit = str(doc["unit"])
    try:
        unit_to_metres(unit)
    except CanopyStereoError as exc:
        raise CanopyStereoError(f"pose file {path}: {exc}") from None
    return unit


def _vector(value, name: str) -> np.ndarray:
    try:
        v = np.asarray(value, np.float64).reshape(3)
    except (TypeError, ValueError):
        raise CanopyStereoError(f"{name} must be 3 numbers") from None
    return v


def read_poses(path) -> PoseSet:
    """Read a ``poses.yaml`` (or a one-view ``pose.yaml``) into a :class:`PoseSet`.

    A ``pose.yaml`` with a single ``pose:`` entry gives a set with one pose
    named ``""``. Raises :class:`CanopyStereoError` naming the bad entry.
    """
    path = Path(path)
    doc = _read_yaml(path)
    unit = _unit_of(doc, path)
    out = PoseSet(unit=unit, source=str(path))
    if "pose" in doc:
        out.poses[""] = check_transform(doc["pose"], f"{path}: pose")
    table = doc.get("turntable")
    if table is not None:
        if not isinstance(table, dict) or "angles_deg" not in table:
            raise CanopyStereoError(f"{path}: 'turntable' needs axis_point, axis_direction and angles_deg")
        point = _vector(table.get("axis_point", [0, 0, 0]), f"{path}: turntable axis_point")
        direction = _vector(table.get("axis_direction", [0, -1, 0]), f"{path}: turntable axis_direction")
        if np.linalg.norm(direction) == 0:
            raise CanopyStereoError(f"{path}: turntable axis_direction must be non-zero")
        angles = table["angles_deg"]
        if not isinstance(angles, dict):
            raise CanopyStereoError(f"{path}: turntable angles_deg must map view names to degrees")
        for name, angle in angles.items():
            try:
                a = float(angle)
            except (TypeError, ValueError):
                raise CanopyStereoError(f"{path}: turntable angle of {name!r} is not a number") from None
            out.poses[str(name)] = turntable_pose(a, point, direction)
    poses = doc.get("poses")
    if poses is not None:
        if not isinstance(poses, dict):
            raise CanopyStereoError(f"{path}: 'poses' must map view names to 4x4 matrices")
        for name, matrix in poses.items():
            out.poses[str(name)] = check_transform(matrix, f"{path}: pose of {name!r}")
    if not out.poses:
        raise CanopyStereoError(f"pose file {path} holds no pose ('poses:', 'pose:' or 'turntable:')")
    return out


def write_poses(path, poses: dict, unit: str, *, comment: str | None = None) -> Path:
    """Write ``poses`` (name -> 4x4) as a ``poses.yaml``; returns the path."""
    path = Path(path)
    unit_to_metres(unit)
    body = {"unit": unit,
            "poses": {str(k): [round(float(v), 10) for v in check_transform(T, f"pose of {k!r}").ravel()]
                      for k, T in poses.items()}}
    header = "".join(f"# {line}\n" for line in (comment or "").splitlines())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(header + yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=200),
                    encoding="utf-8")
    return path


def write_pose(path, T, unit: str) -> Path:
    """Write one view's ``pose.yaml`` (``unit`` + ``pose``: 16 numbers, row-major)."""
    path = Path(path)
    unit_to_metres(unit)
    body = {"unit": unit, "pose": [round(float(v), 10) for v in check_transform(T, "pose").ravel()]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=200),
                    encoding="utf-8")
    return path
