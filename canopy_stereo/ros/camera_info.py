"""A camera driver's ``<camera>/camera_info`` (REP 104) from the rig, for ``camera_node``.

Like usb_cam or v4l2_camera with a calibration file, ``camera_node`` publishes beside
each raw image the ``sensor_msgs/CameraInfo`` of its camera, stamped and framed as the
image: ``K`` and ``D`` of the raw camera, ``R`` the rotation to the rig's rectified
camera and ``P`` the rectified camera's projection (``Tx = -f B`` for the right camera),
i.e. the rig's Fusiello rectification
(:func:`canopy_stereo.geometry.frames.raw_camera_calibration`). image_proc /
stereo_image_proc given these infos rectify exactly as ``rectify_node`` does.

The rig comes from the same parameters as ``rectify_node``'s (the rig file with
``--params-file``, or ``rig_file``); without one, no ``camera_info`` is published.
"""
from __future__ import annotations

from sensor_msgs.msg import CameraInfo

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.frames import raw_camera_calibration
from canopy_stereo.ros.convert import camera_info_msg
from canopy_stereo.ros.params import RIG_PARAMETERS, declare_rig_parameters, rig_from_node, rig_given

CAMERA_SIDES = ("left", "right")


class RawCameraInfoPublisher:
    """``<camera_name>/camera_info`` of one raw camera of the rig (see module docstring).

    Attributes:
        calibration: the camera's :class:`~canopy_stereo.geometry.frames.CameraCalibration`,
            or None (no rig, or a camera name other than ``left``/``right``).
    """

    def __init__(self, node, camera_name: str):
        self.node = node
        self.calibration = None
        self.publisher = None
        if not node.has_parameter(next(iter(RIG_PARAMETERS))):
            declare_rig_parameters(node)
        if camera_name not in CAMERA_SIDES:
            node.get_logger().info(f"camera {camera_name}: not left/right of a rig, no camera_info")
            return
        try:
            rig = rig_from_node(node)
        except RigError as exc:
            if rig_given(node):  # a broken rig stops the node (exit 2), as in the other nodes
                raise
            node.get_logger().info(f"camera {camera_name}: no camera_info ({exc})")
            return
        self.calibration = raw_camera_calibration(rig, camera_name)
        self.publisher = node.make_publisher(CameraInfo, f"{camera_name}/camera_info")

    def publish(self, stamp_ns: int, frame_id: str, image_shape) -> None:
        """Publish the info of a frame of ``image_shape`` (H, W[, C]) just published."""
        if self.publisher is None:
            return
        c = self.calibration
        h, w = image_shape[:2]
        if (w, h) != (c.width, c.height):
            self.node.drop(f"frames are {w}x{h} but the rig's camera is {c.width}x{c.height}",
                           "camera_info")
            return
        self.publisher.publish(camera_info_msg(c, stamp_ns, frame_id=frame_id))
