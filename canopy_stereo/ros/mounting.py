"""The mounting parameters of ``rectify_node``: where the rig sits in a robot's TF tree.

``parent_frame`` (string, "" = the rig's world frame is a root), ``mount`` (seven numbers
``x y z qx qy qz qw``, metres: the rig's world frame in ``parent_frame``), ``camera_mount``
(seven numbers: the raw left camera's optical frame in ``parent_frame``, from a hand-eye
calibration; instead of ``mount``), ``publish_tf`` (false: the robot's URDF owns the camera
frames, nothing goes to ``/tf_static``) and ``frame_prefix`` (prepended to every frame the
rig names). The node only reads them; the frame maths are
:func:`canopy_stereo.geometry.frames.mount_transform` and
:func:`~canopy_stereo.geometry.frames.prefixed_frames`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.frames import FrameNames, mount_transform, pose_matrix, prefixed_frames
from canopy_stereo.io.rig import Rig

#: parameter -> description
MOUNT_PARAMETERS = {
    "parent_frame": "robot frame the rig is mounted on, e.g. base_link or tool0 ('' = the rig's world "
                    "frame is a root of its own tree)",
    "mount": "seven numbers x y z qx qy qz qw (metres, unit quaternion): the rig's world frame in "
             "parent_frame (unset = identity)",
    "camera_mount": "seven numbers x y z qx qy qz qw: the raw left camera's optical frame in parent_frame "
                    "(hand-eye calibration), instead of mount",
    "publish_tf": "publish the rig's frames on /tf_static (false when the robot's URDF owns them)",
    "frame_prefix": "prepended to every frame the rig names, e.g. rig_a/ (not to parent_frame)",
}


@dataclass(frozen=True)
class Mounting:
    """The mounting parameters, read and checked.

    Attributes:
        parent_frame: robot frame ("" = none).
        mount, camera_mount: seven numbers each, or None (see the module docstring).
        publish_tf: whether the rig's frames go to ``/tf_static``.
        frame_prefix: prefix of the rig's frame ids.
    """

    parent_frame: str = ""
    mount: tuple | None = None
    camera_mount: tuple | None = None
    publish_tf: bool = True
    frame_prefix: str = ""

    def transform(self, rig: Rig) -> np.ndarray | None:
        """``T_parent_world`` (4x4, metres) for ``rig``, or None when not mounted."""
        if not self.parent_frame:
            return None
        return mount_transform(rig, mount=self.mount, camera_mount=self.camera_mount)


def declare_mount_parameters(node) -> None:
    """Declare the mounting parameters (read-only; see the module docstring)."""
    for name, desc in MOUNT_PARAMETERS.items():
        default = {"parent_frame": "", "publish_tf": True, "frame_prefix": ""}.get(name)
        node.declare_parameter(name, default, ParameterDescriptor(description=desc, read_only=True,
                                                                  dynamic_typing=default is None))


def _numbers(node, name):
    value = node.get_parameter(name).value
    if value is None or (hasattr(value, "__len__") and len(value) == 0):
        return None
    if isinstance(value, str) or not hasattr(value, "__len__"):
        raise RigError(f"{name} must be seven numbers x y z qx qy qz qw, got {value!r}")
    return list(value)


def mount_from_node(node) -> Mounting:
    """The node's :class:`Mounting` (raises :class:`RigError` naming the bad parameter)."""
    parent = str(node.get_parameter("parent_frame").value or "")
    prefix = str(node.get_parameter("frame_prefix").value or "")
    mount, camera_mount = _numbers(node, "mount"), _numbers(node, "camera_mount")
    if (mount is not None or camera_mount is not None) and not parent:
        raise RigError("mount/camera_mount need parent_frame (the robot frame the rig is mounted on)")
    if mount is not None and camera_mount is not None:
        raise RigError("give the rig's mount or the left camera's mount (camera_mount), not both")
    if parent.startswith("/"):
        raise RigError(f"parent_frame must not start with '/' (tf2 frame ids do not), got {parent!r}")
    prefixed_frames(FrameNames(), prefix)  # raise on a bad prefix before anything is built
    for name, values in (("mount", mount), ("camera_mount", camera_mount)):
        if values is not None:
            pose_matrix(values, name=name)
    return Mounting(parent_frame=parent, mount=None if mount is None else tuple(mount),
                    camera_mount=None if camera_mount is None else tuple(camera_mount),
                    publish_tf=bool(node.get_parameter("publish_tf").value), frame_prefix=prefix)
