"""The rig as ``rectify_node`` holds it, for the nodes downstream: the ``stereo_geometry`` topic.

Camera matrices enter the graph once, as ``rectify_node``'s parameters (the rig file).
Downstream nodes take the geometry from the messages they receive, as image_pipeline's
do: ``disparity_node`` from the rectified ``CameraInfo`` pair, ``point_cloud_node`` from
the ``DisparityImage`` and the left rectified ``CameraInfo`` (image_geometry's Q matrix, in
the left rectified optical frame). What a ``CameraInfo`` cannot carry, ``rectify_node``
publishes once on ``stereo_geometry`` (``std_msgs/String`` holding JSON; reliable,
transient local, so a node started later still gets it):

* ``transforms``: the static transforms of the rig (the ones on ``/tf_static``), which
  ``point_cloud_node`` uses to put the cloud in the world frame without a TF library;
* for a Hartley (projective) rectification, which has no metric rectified camera, the
  homographies and world-frame ``P`` matrices its exact back-mapping + DLT triangulation
  needs.

So two nodes can never disagree about the rig: only ``rectify_node`` reads it.

JSON fields: ``format`` (1), ``method`` (``fusiello``/``hartley``), ``world_frame``,
``world_unit``, ``metres_per_unit``, ``image_size`` ``[w, h]``, ``P_left``/``P_right``
(12 numbers, world units), ``H_left``/``H_right`` (9 numbers), ``frames`` (name ->
frame id: ``world``, ``world_z_up``, ``raw_left``, ``raw_right``, ``rect_left``,
``rect_right``, ``parent``: the robot frame the rig is mounted on, "" = none),
``transforms`` (list of ``{"parent", "child", "matrix"}``, ``matrix`` =
16 numbers, row-major 4x4 ``T_parent_child`` in metres).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np
from std_msgs.msg import String

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.frames import FrameNames, stereo_transforms
from canopy_stereo.geometry.rectification import Rectification
from canopy_stereo.geometry.transforms import invert_transform

#: Topic (relative to the node namespace) of the geometry message.
STEREO_GEOMETRY_TOPIC = "stereo_geometry"
FORMAT = 1


def _floats(a) -> list[float]:
    return [float(v) for v in np.asarray(a, np.float64).ravel()]


def stereo_geometry_msg(rig, rect: Rectification, names: FrameNames, *, transforms=None) -> String:
    """The ``stereo_geometry`` message of a rig and its rectification (``transforms``: the
    rig's ``(parent, child, T)`` list when already computed, e.g. with a mount; default
    :func:`~canopy_stereo.geometry.frames.stereo_transforms` of the unmounted rig)."""
    if transforms is None:
        transforms = stereo_transforms(rig, rect, names=names)
    data = {
        "format": FORMAT, "method": rect.method, "world_frame": names.world,
        "world_unit": rig.world_unit, "metres_per_unit": rig.metres_per_unit,
        "image_size": [int(v) for v in rect.size],
        "P_left": _floats(rig.P_left), "P_right": _floats(rig.P_right),
        "H_left": _floats(rect.H_left), "H_right": _floats(rect.H_right),
        "frames": {k: getattr(names, k) for k in FrameNames.__dataclass_fields__},
        "transforms": [{"parent": p, "child": c, "matrix": _floats(T)}
                       for p, c, T in transforms],
    }
    return String(data=json.dumps(data))


@dataclass
class StereoGeometry:
    """Parsed ``stereo_geometry`` (see the module docstring)."""

    method: str
    world_frame: str
    metres_per_unit: float
    image_size: tuple[int, int]
    P_left: np.ndarray
    P_right: np.ndarray
    H_left: np.ndarray
    H_right: np.ndarray
    frames: dict
    transforms: dict = field(default_factory=dict)  # child -> (parent, T_parent_child)

    def rectification(self) -> Rectification:
        """The rectification's homographies (enough for back-mapping + triangulation)."""
        return Rectification(H_left=self.H_left, H_right=self.H_right, size=self.image_size,
                             method=self.method)

    def lookup(self, target: str, source: str) -> np.ndarray:
        """``T_target_source`` (4x4, metres) through the transform tree; raises
        :class:`RigError` when the frames are not connected."""
        def chain(frame):  # frame -> root: list of (frame, T_root_frame)
            T = np.eye(4)
            out = [(frame, T)]
            seen = {frame}
            while frame in self.transforms:
                parent, T_pf = self.transforms[frame]
                if parent in seen:
                    raise RigError(f"stereo_geometry: the transforms loop at {parent}")
                seen.add(parent)
                T = T_pf @ T
                frame = parent
                out.append((frame, T))
            return out

        up_s = dict(chain(source))   # frame -> T_frame_source
        for frame, T_frame_target in chain(target):
            if frame in up_s:
                return invert_transform(T_frame_target) @ up_s[frame]
        raise RigError(f"stereo_geometry: no transform connects {source!r} to {target!r}")


def parse_stereo_geometry(msg) -> StereoGeometry:
    """Read a ``stereo_geometry`` message (raises :class:`RigError` naming the problem)."""
    try:
        data = json.loads(msg.data)
    except (TypeError, ValueError) as exc:
        raise RigError(f"stereo_geometry is not JSON: {exc}") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise RigError(f"stereo_geometry has format {data.get('format') if isinstance(data, dict) else None!r}, "
                       f"expected {FORMAT}")
    try:
        def mat(name, shape):
            a = np.asarray(data[name], np.float64)
            if a.size != int(np.prod(shape)) or not np.all(np.isfinite(a)):
                raise RigError(f"stereo_geometry: {name} must be {np.prod(shape)} finite numbers")
            return a.reshape(shape)

        transforms = {}
        for t in data["transforms"]:
            T = np.asarray(t["matrix"], np.float64)
            if T.size != 16 or not np.all(np.isfinite(T)):
                raise RigError(f"stereo_geometry: transform to {t['child']!r} must be 16 finite numbers")
            transforms[str(t["child"])] = (str(t["parent"]), T.reshape(4, 4))
        w, h = (int(v) for v in data["image_size"])
        return StereoGeometry(
            method=str(data["method"]), world_frame=str(data["world_frame"]),
            metres_per_unit=float(data["metres_per_unit"]), image_size=(w, h),
            P_left=mat("P_left", (3, 4)), P_right=mat("P_right", (3, 4)),
            H_left=mat("H_left", (3, 3)), H_right=mat("H_right", (3, 3)),
            frames=dict(data["frames"]), transforms=transforms)
    except (KeyError, TypeError, ValueError) as exc:
        raise RigError(f"stereo_geometry is incomplete or malformed: {exc!r}") from None
