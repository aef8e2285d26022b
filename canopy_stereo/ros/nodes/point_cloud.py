"""``point_cloud_node``: the paper's triangulation of a rectified disparity into a metric cloud.

Subscribes ``disparity`` (``stereo_msgs/DisparityImage``), ``left/image_rect_color``
(bgr8) and, with ``use_mask``, ``left/mask`` (mono8, 0 = background), pairs them
by exact stamp, and publishes ``points2`` (``sensor_msgs/PointCloud2``).

Every valid rectified match ``(u, v) <-> (u - d, v)`` is mapped back to the
original images through the inverse rectifying homographies and triangulated
with the world-frame projection matrices of the rig
(:func:`canopy_stereo.geometry.triangulation.triangulate_disparity_points`), so x, y, z
are in the rig's world frame, converted to metres. Fields: float32 ``x y z`` and
packed float32 ``rgb`` from the rectified left colour image.

Parameters: the rig, ``method``, ``H_left``/``H_right`` (as for ``rectify_node``),
``frame_id`` (default ``canopy_world``), ``organized`` (true: one point per
rectified pixel, NaN where invalid; false: valid points only), ``use_mask``,
``queue_size``, ``reliability``.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.geometry.triangulation import triangulate_disparity_points
from canopy_stereo.ros.convert import (COLOUR_ENCODINGS, msg_to_bgr, msg_to_disparity, msg_to_image, pack_bgr_image,
                                       points_to_cloud2, stamp_to_ns)
from canopy_stereo.ros.limits import check_disparity_msg, check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rectification_from_node, rig_from_node
from canopy_stereo.ros.sync import ExactTimeSynchronizer


def cloud_from_disparity(disp: np.ndarray, left_bgr: np.ndarray, rig, rect, mask=None,
                         organized: bool = True):
    """World points (metres) and packed colours of the valid rectified left pixels.

    Args:
        disp: float32 (Hr, Wr) rectified disparity ``u_left - u_right``, invalid < 0.
        left_bgr: uint8 (Hr, Wr, 3) rectified left image.
        rig, rect: the rig and its rectification.
        mask: optional (Hr, Wr) mask, 0 = drop the pixel.
        organized: return the rectified grid (NaN where no point) rather than
            only the valid points.

    Returns ``(points, rgb)``: float32 metres and the packed float32 ``rgb`` of
    PointCloud2 (:func:`~canopy_stereo.ros.convert.pack_rgb`), (Hr, Wr, 3) and
    (Hr, Wr) when ``organized``, else (N, 3) and (N,).
    """
    w, h = rect.size
    if disp.shape != (h, w):
        raise ImageError(f"disparity is {disp.shape[1]}x{disp.shape[0]} but the rig's rectified "
                         f"images are {w}x{h}")
    if left_bgr.shape[:2] != disp.shape:
        raise ImageError(f"colour image is {left_bgr.shape[1]}x{left_bgr.shape[0]}, "
                         f"disparity {w}x{h}")
    if mask is not None and mask.shape != disp.shape:
        raise ImageError(f"mask is {mask.shape[1]}x{mask.shape[0]}, disparity {w}x{h}")
    points, index = triangulate_disparity_points(disp, rect, rig.P_left, rig.P_right,
                                                 scale=rig.metres_per_unit, mask=mask,
                                                 organized=organized)
    rgb = pack_bgr_image(left_bgr).reshape(-1)
    if organized:
        return points.reshape(h, w, 3), rgb.reshape(h, w)
    return points, rgb[index]


class PointCloudNode(CanopyNode):
    """Exact-time pairing of disparity, colour (and mask) + triangulation."""

    def __init__(self, node_name: str = "point_cloud_node", **kwargs):
        super().__init__(node_name, **kwargs)
        declare_rig_parameters(self)
        self.declare_parameter("frame_id", "canopy_world", ParameterDescriptor(
            description="frame of the cloud: the rig's world frame"))
        self.declare_parameter("organized", False, ParameterDescriptor(
            description="true: organized cloud on the rectified grid with NaN; false: valid points"))
        self.declare_parameter("use_mask", False, ParameterDescriptor(
            description="keep only pixels of left/mask (255 = plant)", read_only=True))
        self.declare_parameter("queue_size", 5, ParameterDescriptor(read_only=True))
        self.rig = rig_from_node(self)
        self.rect = rectification_from_node(self, self.rig)
        self.use_mask = bool(self.get_parameter("use_mask").value)
        n = 3 if self.use_mask else 2
        self.sync = ExactTimeSynchronizer(n, int(self.get_parameter("queue_size").value))
        self.pub = self.make_publisher(PointCloud2, "points2")
        self.sub_disp = self.make_subscription(DisparityImage, "disparity", lambda m: self._on(0, m))
        self.sub_color = self.make_subscription(Image, "left/image_rect_color", lambda m: self._on(1, m))
        if self.use_mask:
            self.sub_mask = self.make_subscription(Image, "left/mask", lambda m: self._on(2, m))
        self.get_logger().info(f"triangulating in frame {self.get_parameter('frame_id').value} "
                               f"({'masked' if self.use_mask else 'unmasked'})")

    def _on(self, stream: int, msg) -> None:
        what = ("disparity", "colour image", "mask")[stream]
        self.count(f"{what}_received")
        try:
            if stream == 0:
                check_disparity_msg(msg, expected_size=self.rect.size)
                # message convention d - doffs, NaN invalid -> rectified u_left - u_right, -1 invalid
                d = msg_to_disparity(msg).disparity + np.float32(self.rect.doffs)
                item = np.where(np.isfinite(d), d, np.float32(-1))
            elif stream == 1:
                check_image_msg(msg, expected_size=self.rect.size, encodings=COLOUR_ENCODINGS)
                item = msg_to_bgr(msg)
            else:
                check_image_msg(msg, expected_size=self.rect.size, encodings=("mono8", "8UC1"))
                item = msg_to_image(msg, ("mono8", "8UC1"))
        except CanopyStereoError as exc:
            self.drop(str(exc), what)
            return
        stamp = stamp_to_ns(msg.header.stamp)
        items, dropped = self.sync.push(stream, stamp, item)
        for d in dropped:
            self.drop(d.reason, ("disparity", "colour image", "mask")[d.stream])
        if items is not None:
            self._publish(stamp, *items)

    def _publish(self, stamp_ns: int, disp, bgr, mask=None) -> None:
        organized = bool(self.get_parameter("organized").value)
        points, rgb = cloud_from_disparity(disp, bgr, self.rig, self.rect, mask, organized)
        self.pub.publish(points_to_cloud2(points, None, stamp_ns, self.get_parameter("frame_id").value,
                                          organized=organized, rgb=rgb))
        self.count("clouds_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo point_cloud_node --ros-args --params-file RIG.yaml``."""
    return run_node(PointCloudNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
