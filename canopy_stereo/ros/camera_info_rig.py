"""A rig from a driver's two raw ``camera_info`` topics (``rectify_node``'s ``use_camera_info``).

image_pipeline takes the calibration from the cameras' ``CameraInfo`` (REP 104: ``K``, ``D``,
``R``, ``P`` with the right camera's ``Tx = -f B``), not from a file. :class:`CameraInfoRig`
subscribes ``left/camera_info`` and ``right/camera_info``, and once both have arrived turns
them into a :class:`~canopy_stereo.geometry.rig.Rig` (world frame = the left camera's optical
frame, metres) with the same checks as an imported ROS calibration
(:func:`canopy_stereo.io.calibration_import.ros.rig_from_camera_infos`). A pair that is not one
stereo calibration is dropped with its reason, and the next pair is tried. The first good
pair decides the rig.
"""
from __future__ import annotations

from sensor_msgs.msg import CameraInfo

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.frames import CameraCalibration
from canopy_stereo.io.calibration_import.ros import rig_from_camera_infos
from canopy_stereo.ros.convert import camera_info_matrices

#: The raw camera_info topics (relative to the node's namespace).
CAMERA_INFO_TOPICS = ("left/camera_info", "right/camera_info")


def calibration_from_msg(info: CameraInfo) -> CameraCalibration:
    """A ``CameraInfo`` message's matrices as a :class:`CameraCalibration` (unchecked)."""
    K, D, R, P = camera_info_matrices(info)
    return CameraCalibration(width=int(info.width), height=int(info.height), K=K, D=D, R=R, P=P,
                             distortion_model=str(info.distortion_model))


class CameraInfoRig:
    """Wait for ``left/camera_info`` and ``right/camera_info`` and call ``on_rig(rig)`` once.

    Args:
        node: a :class:`~canopy_stereo.ros.nodes.base.CanopyNode` (its subscriptions, drops, log).
        on_rig: called with the :class:`~canopy_stereo.geometry.rig.Rig` of the first good pair.
    """

    def __init__(self, node, on_rig):
        self.node, self.on_rig = node, on_rig
        self.latest: list[CameraInfo | None] = [None, None]
        self.rig = None
        self.subscriptions = [node.make_subscription(CameraInfo, topic, lambda m, s=side: self._on_info(s, m))
                              for side, topic in enumerate(CAMERA_INFO_TOPICS)]

    def _on_info(self, side: int, msg: CameraInfo) -> None:
        if self.rig is not None:
            return
        self.latest[side] = msg
        left, right = self.latest
        if left is None or right is None:
            return
        try:
            rig = rig_from_camera_infos(calibration_from_msg(left), calibration_from_msg(right),
                                        source="camera_info")
        except CanopyStereoError as exc:
            self.latest = [None, None]
            self.node.drop(str(exc), "camera_info pair")
            return
        self.rig = rig
        for sub in self.subscriptions:  # the rig is decided: no more camera_info needed
            self.node.destroy_subscription(sub)
        self.on_rig(rig)
