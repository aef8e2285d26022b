"""``rectify_node``: pair raw left/right frames by approximate time, undistort and rectify.

Subscribes ``left/image_raw`` and ``right/image_raw`` (``sensor_msgs/Image``,
bgr8/rgb8/mono8/bgra8/rgba8 of the rig's image size). Publishes, with the left
frame's stamp:

* ``left/image_rect``, ``right/image_rect``: mono8 rectified images;
* ``left/image_rect_color``: bgr8 rectified left image;
* ``left/camera_info``, ``right/camera_info``: the rectified cameras in ROS
  conventions (Fusiello only: a Hartley rectification is projective and has no
  metric rectified camera).

Parameters: the rig (:mod:`canopy_stereo.ros.params`), ``method``,
``H_left``/``H_right``, ``sync_slop`` (s), ``queue_size``, ``frame_id`` of the
rectified images, ``reliability``.
"""
from __future__ import annotations

from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import CameraInfo, Image

from canopy_stereo.geometry.rectification import StereoRectifier
from canopy_stereo.io.images import to_gray
from canopy_stereo.ros.convert import (COLOUR_ENCODINGS, image_to_msg, msg_to_bgr, rectified_camera_info,
                                       stamp_to_ns)
from canopy_stereo.ros.limits import check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rectification_from_node, rig_from_node
from canopy_stereo.ros.sync import ApproximateTimePairer


class RectifyNode(CanopyNode):
    """Approximate-time pairing + rectification (see module docstring)."""

    def __init__(self, node_name: str = "rectify_node", **kwargs):
        super().__init__(node_name, **kwargs)
        declare_rig_parameters(self)
        ro = ParameterDescriptor(read_only=True)
        self.declare_parameter("sync_slop", 0.015, ParameterDescriptor(
            description="largest stamp difference of a left/right pair, seconds", read_only=True))
        self.declare_parameter("queue_size", 5, ParameterDescriptor(
            description="frames per camera kept while waiting for a partner", read_only=True))
        self.declare_parameter("frame_id", "stereo_rect_left", ro)
        self.rig = rig_from_node(self)
        self.rect = rectification_from_node(self, self.rig)
        self.rectifier = StereoRectifier(self.rig, self.rect)
        self.frame_id = self.get_parameter("frame_id").value
        self.pairer = ApproximateTimePairer(float(self.get_parameter("sync_slop").value),
                                            int(self.get_parameter("queue_size").value))
        self.pub_left = self.make_publisher(Image, "left/image_rect")
        self.pub_right = self.make_publisher(Image, "right/image_rect")
        self.pub_color = self.make_publisher(Image, "left/image_rect_color")
        self.pub_info_left = self.make_publisher(CameraInfo, "left/camera_info")
        self.pub_info_right = self.make_publisher(CameraInfo, "right/camera_info")
        self.sub_left = self.make_subscription(Image, "left/image_raw", lambda m: self._on_image(0, m))
        self.sub_right = self.make_subscription(Image, "right/image_raw", lambda m: self._on_image(1, m))
        if self.rect.method != "fusiello":
            self.get_logger().info("hartley rectification: no camera_info is published "
                                   "(a projective rectification has no metric camera)")
        w, h = self.rig.image_size
        self.get_logger().info(f"rectifying {w}x{h} pairs ({self.rect.method}), "
                               f"sync slop {self.pairer.slop_ns / 1e9:g} s")

    def _on_image(self, side: int, msg: Image) -> None:
        name = ("left", "right")[side]
        self.count(f"{name}_received")
        try:
            check_image_msg(msg, expected_size=self.rig.image_size, encodings=COLOUR_ENCODINGS)
            bgr = msg_to_bgr(msg, expected_size=self.rig.image_size)
        except Exception as exc:
            self.drop(str(exc), f"{name} frame")
            return
        pair, dropped = self.pairer.push(side, stamp_to_ns(msg.header.stamp), bgr)
        for d in dropped:
            self.drop(d.reason, f"{('left', 'right')[d.stream]} frame")
        if pair is not None:
            self._publish(pair.stamps_ns[0], *pair.items)

    def _publish(self, stamp_ns: int, left_bgr, right_bgr) -> None:
        left_r, right_r = self.rectifier.rectify(left_bgr, right_bgr)
        fid = self.frame_id
        self.pub_color.publish(image_to_msg(left_r, "bgr8", stamp_ns, fid))
        self.pub_left.publish(image_to_msg(to_gray(left_r), "mono8", stamp_ns, fid))
        self.pub_right.publish(image_to_msg(to_gray(right_r), "mono8", stamp_ns, fid))
        if self.rect.K_rect_left is not None:
            baseline_m = self.rect.baseline * self.rig.metres_per_unit
            self.pub_info_left.publish(rectified_camera_info(
                self.rect.K_rect_left, self.rect.size, baseline_m, "left", stamp_ns, fid))
            self.pub_info_right.publish(rectified_camera_info(
                self.rect.K_rect_right, self.rect.size, baseline_m, "right", stamp_ns, fid))
        self.count("pairs_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo rectify_node --ros-args --params-file RIG.yaml``."""
    return run_node(RectifyNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
