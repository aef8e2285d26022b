"""``point_cloud_node``: a rectified disparity -> metric cloud ``points2`` and depth ``left/depth``.

Subscribes ``disparity`` (``stereo_msgs/DisparityImage``), ``left/image_rect_color``
(bgr8), ``left/image_rect/camera_info`` (the rectified left camera) and, with
``use_mask``, ``left/mask`` (mono8, 0 = background), pairs them by exact stamp, and
publishes ``points2`` (``sensor_msgs/PointCloud2``: float32 ``x y z`` in metres and
packed float32 ``rgb`` from the rectified left colour image) and, for a calibrated
rectification, the REP 118 depth image ``left/depth`` (32FC1, metres along the
rectified left optical axis, NaN = no depth; the same pixels as ``points2``) with its
camera ``left/depth/camera_info`` (the rectified left camera), so depth_image_proc and
RGB-D consumers work; both are built and sent only while someone subscribes to either.

Only the pixels that can hold a point are visited: a dense cloud (``organized`` false) is built
from the ``DisparityImage``'s ``valid_window`` (no disparity is valid outside it:
``disparity_node``'s ``roi`` window, or its valid pixels' box), the colours packed there only.

This node holds no rig: the geometry comes from the messages, as in image_pipeline.

* Calibrated (Fusiello) rectification: each valid pixel ``(u, v)`` with disparity ``d``
  is reprojected with image_geometry's 4x4 ``Q`` built from the left ``CameraInfo`` and
  the ``DisparityImage``'s ``f``, ``t`` (``Z = f t / d``, ``X = (u - cx) Z / fx``,
  ``Y = (v - cy) Z / fy``) into the rectified left optical frame (the ``CameraInfo``'s
  ``frame_id``); for the world frame it is then moved by ``T_world_optical`` from
  rectify_node's latched ``stereo_geometry`` (the transforms it also publishes on
  ``/tf_static``). The same points, to float rounding, as back-mapping the matches to
  the raw images and triangulating them with the rig's ``P``.
* Hartley (projective) rectification (uncalibrated ``CameraInfo``): the paper's exact
  path, back-mapping through the homographies and DLT triangulation with the world-frame
  ``P`` matrices, both from ``stereo_geometry``. No depth image.

Parameters: ``cloud_frame`` (``world``, the default: the rig's world frame, the paper's
metric frame; ``world_z_up``: the same turned so that z points up, for RViz; ``optical``:
the rectified left optical frame, needs no ``stereo_geometry``; ``parent``: the robot frame
``rectify_node`` is mounted on, through its mount), ``frame_id`` (the name
written for the world frame; default "": rectify_node's ``world_frame``,
``canopy_world``), ``organized`` (true: one point per rectified pixel, NaN where
invalid; false: valid points only), ``use_mask``, ``queue_size``, ``reliability``.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.serialization import serialize_message
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import String
from stereo_msgs.msg import DisparityImage

from canopy_stereo.bag.pairing import ExactTimeSynchronizer
from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.geometry.cloud_assembly import (
    check_cloud_inputs,
    cloud_from_disparity,
    disparity_image_reprojection,
    offset_reprojection,
    window_slices,
)
from canopy_stereo.geometry.frames import reproject_disparity_records
from canopy_stereo.geometry.transforms import transform_points
from canopy_stereo.ros.cdr_views import disparity_view, image_view
from canopy_stereo.ros.convert import (
    COLOUR_ENCODINGS,
    camera_info_matrices,
    depth_to_msg,
    disparity_to_msg,
    image_to_msg,
    is_calibrated,
    msg_to_bgr,
    msg_to_disparity,
    msg_to_image,
    pack_bgr_image,
    points_to_cloud2,
    records_to_cloud2,
    stamp_to_ns,
)
from canopy_stereo.ros.limits import check_disparity_msg, check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.nodes.rectify import RECT_INFO_TOPICS
from canopy_stereo.ros.stereo_geometry import STEREO_GEOMETRY_TOPIC, parse_stereo_geometry
from canopy_stereo.ros.tf import latched_qos

#: Values of the ``cloud_frame`` parameter.
CLOUD_FRAMES = ("world", "world_z_up", "optical", "parent")


class PointCloudNode(CanopyNode):
    """Exact-time pairing of disparity, colour, camera_info (and mask) + reprojection."""

    def __init__(self, node_name: str = "point_cloud_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_text("frame_id", "", "name written for the world frame ('' = rectify_node's "
                          "world_frame)")
        self.declare_text("cloud_frame", "world", "frame of points2: world (the rig's metric frame), "
                          "world_z_up (z up, for RViz), optical (the rectified left optical frame) or parent "
                          "(the robot frame rectify_node is mounted on, by its mount)",
                          choices=CLOUD_FRAMES)
        self.declare_flag("organized", False, "true: organized cloud on the rectified grid, NaN where "
                          "invalid; false: valid points only")
        self.declare_flag("use_mask", False, "keep only the pixels of left/mask (255 = plant)",
                          read_only=True)
        self.declare_number("queue_size", 15, "stamps kept while waiting for the other inputs with "
                            "the same stamp (colour images arrive a disparity computation earlier)",
                            minimum=1, maximum=100, read_only=True)
        self.declare_frame_size()
        self.use_mask = bool(self.get_parameter("use_mask").value)
        problem = _cloud_frame_problem(self.get_parameter("cloud_frame").value)
        if problem:
            raise CanopyStereoError(problem)
        # (checked here and on every change, so the frame code below can trust the value)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.geometry = None
        # synced frames that arrived before rectify_node's latched stereo_geometry (a race at start:
        # the latched sample and the first images travel on different topics); published as soon
        # as the geometry arrives, the oldest dropped beyond queue_size
        self.waiting_for_geometry: list[tuple[int, tuple]] = []
        self.expected_size = None  # (width, height) of the latest rectified camera_info
        # streams: 0 disparity, 1 colour, 2 left camera_info, 3 mask
        n = 4 if self.use_mask else 3
        self.sync = ExactTimeSynchronizer(n, int(self.get_parameter("queue_size").value),
                                          on_jump=self.time_jump_handler(_STREAMS))
        self.pub = self.make_publisher(PointCloud2, "points2")
        self.pub_depth = self.make_publisher(Image, "left/depth")
        self.pub_depth_info = self.make_publisher(CameraInfo, "left/depth/camera_info")
        self.sub_geometry = self.create_subscription(String, STEREO_GEOMETRY_TOPIC,
                                                     self.guarded(self._on_geometry), latched_qos())
        w, h = self.warm_up_size()
        self.warm_up(f"reprojection of {w}x{h} disparities", self._warm_up)
        # the large inputs are read in place from the serialized messages (cdr_views: no deserialisation)
        self.sub_disp = self.make_subscription(DisparityImage, "disparity", lambda m: self._on(0, m),
                                               parse=disparity_view)
        self.sub_color = self.make_subscription(Image, "left/image_rect_color", lambda m: self._on(1, m),
                                                parse=image_view)
        self.sub_info = self.make_subscription(CameraInfo, RECT_INFO_TOPICS[0], lambda m: self._on(2, m))
        if self.use_mask:
            self.sub_mask = self.make_subscription(Image, "left/mask", lambda m: self._on(3, m), parse=image_view)
        self.get_logger().info(f"points2 in the {self.get_parameter('cloud_frame').value} frame "
                               f"({'masked' if self.use_mask else 'unmasked'})")

    @staticmethod
    def _check_parameters(parameters) -> SetParametersResult:
        for p in parameters:
            problem = _cloud_frame_problem(p.value) if p.name == "cloud_frame" else None
            if problem:
                return SetParametersResult(successful=False, reason=problem)
        return SetParametersResult(successful=True)

    def _warm_up(self) -> None:
        """A disparity of the rig's size through conversion and reprojection into cloud and
        depth messages (the kernel loaded or compiled, the buffers allocated), nothing published;
        as messages (an intra-process bus) and as views of serialized ones (read-only arrays)."""
        w, h = self.warm_up_size()
        rng = np.random.default_rng(0)
        disp = rng.uniform(10.0, 40.0, (h, w)).astype(np.float32)
        disp[::7] = np.nan
        Q = np.array([[1.0, 0, 0, -w / 2], [0, 1, 0, -h / 2], [0, 0, 0, 500.0], [0, 0, 10.0, 0]])
        messages = (disparity_to_msg(disp, 500.0, 0.1, 0.0, 64.0),
                    image_to_msg(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), "bgr8"),
                    image_to_msg(np.full((h, w), 255, np.uint8), "mono8"))
        views = (disparity_view(serialize_message(messages[0])), image_view(serialize_message(messages[1])),
                 image_view(serialize_message(messages[2])))
        for wire, colour, mask_msg in (messages, views):
            check_disparity_msg(wire)  # the limits' and the wire conversion's kernels
            frame = msg_to_disparity(wire)
            bgr = msg_to_bgr(colour)
            mask = msg_to_image(mask_msg) if self.use_mask else None
            for organized in (False, True):
                records, depth = reproject_disparity_records(frame.disparity, Q, T=np.eye(4), bgr=bgr,
                                                             mask=mask, organized=organized)
                records_to_cloud2(records, 1, frame_id="", organized_shape=(h, w) if organized else None)
            # windows of the maps (not contiguous: the kernel's other specialisations), with and without depth
            for depth_wanted in (False, True):
                reproject_disparity_records(frame.disparity[1:, 1:], Q, T=np.eye(4), bgr=bgr[1:, 1:],
                                            mask=None if mask is None else mask[1:, 1:], depth=depth_wanted)
        depth_to_msg(depth, 1, frame_id="")

    def _on_geometry(self, msg: String) -> None:
        try:
            self.geometry = parse_stereo_geometry(msg)
        except CanopyStereoError as exc:
            self.drop(str(exc), "stereo_geometry")
            return
        self.count("geometry_received")
        waiting, self.waiting_for_geometry = self.waiting_for_geometry, []
        for stamp, items in waiting:
            self._publish_or_drop(stamp, items)

    def _on(self, stream: int, msg) -> None:
        what = _STREAMS[stream]
        self.count(f"{what}_received")
        try:
            if stream == 0:
                check_disparity_msg(msg, expected_size=self.expected_size)
                item = msg_to_disparity(msg)
            elif stream == 1:
                check_image_msg(msg, expected_size=self.expected_size, encodings=COLOUR_ENCODINGS)
                item = msg_to_bgr(msg)
            elif stream == 2:
                if msg.width > 0 and msg.height > 0:  # inputs must have the rectified camera's size
                    self.expected_size = (int(msg.width), int(msg.height))
                item = msg
            else:
                check_image_msg(msg, expected_size=self.expected_size, encodings=("mono8", "8UC1"))
                item = msg_to_image(msg, ("mono8", "8UC1"))
        except CanopyStereoError as exc:
            self.drop(str(exc), what)
            return
        stamp = stamp_to_ns(msg.header.stamp)
        items, dropped = self.sync.push(stream, stamp, item)
        self.drop_unpaired(dropped, _STREAMS)
        if items is None:
            return
        if self.geometry is None and self._needs_geometry(items[2]):
            self.waiting_for_geometry.append((stamp, items))
            limit = int(self.get_parameter("queue_size").value)
            while len(self.waiting_for_geometry) > limit:
                self.waiting_for_geometry.pop(0)
                self.drop(f"no {STEREO_GEOMETRY_TOPIC} from rectify_node after {limit} frames "
                          f"(needed for the {self.get_parameter('cloud_frame').value} frame)", "frame")
            return
        self._publish_or_drop(stamp, items)

    def _needs_geometry(self, info: CameraInfo) -> bool:
        return self.get_parameter("cloud_frame").value != "optical" or not is_calibrated(info)

    def _publish_or_drop(self, stamp: int, items: tuple) -> None:
        try:
            self._publish(stamp, *items)
        except CanopyStereoError as exc:
            self.drop(str(exc), "frame")

    def _world_frame(self) -> str:
        return self.get_parameter("frame_id").value or (
            self.geometry.world_frame if self.geometry is not None else "canopy_world")

    def _publish(self, stamp_ns: int, frame, bgr, info: CameraInfo, mask=None) -> None:
        organized = bool(self.get_parameter("organized").value)
        cloud_frame = self.get_parameter("cloud_frame").value
        if self._needs_geometry(info):
            if self.geometry is None:
                raise CanopyStereoError(f"no {STEREO_GEOMETRY_TOPIC} from rectify_node yet (needed for "
                                        f"the {cloud_frame} frame)")
        h, w = frame.disparity.shape
        check_cloud_inputs(frame.disparity, bgr, mask=mask)
        if (info.width, info.height) != (w, h):
            raise ImageError(f"camera_info is {info.width}x{info.height}, disparity {w}x{h}")
        optical = info.header.frame_id
        if is_calibrated(info):
            Q = disparity_image_reprojection(frame.f, frame.t, camera_info_matrices(info)[3])
            if cloud_frame == "optical":
                T, frame_id = None, optical
            else:
                target = self._target_frame(cloud_frame)
                T = self.geometry.lookup(target, optical)
                frame_id = self._world_frame() if cloud_frame == "world" else target
            # only the pixels that can hold a point: the DisparityImage's valid_window (a dense cloud;
            # disparity_node's roi window, or its valid pixels' box), colours packed there only
            rows, cols = (slice(0, h), slice(0, w)) if organized else window_slices(frame.valid_window, (h, w))
            Qc = offset_reprojection(Q, cols.start, rows.start)
            # x, y, z and rgb (packed from the window's BGR for the kept points only) written by the
            # kernel into the cloud's rows (one copy into the message)
            # (the windows are read in place; the depth image only built when someone reads it)
            depth_wanted = self._depth_wanted()
            records, depth_kept = reproject_disparity_records(
                frame.disparity[rows, cols], Qc, T=T, bgr=bgr[rows, cols],
                mask=None if mask is None else mask[rows, cols], organized=organized, depth=depth_wanted)
            if depth_wanted:  # REP 118 depth of the same pixels, when someone reads it
                depth = depth_kept
                if depth.shape != (h, w):
                    depth = np.full((h, w), np.nan, np.float32)
                    depth[rows, cols] = depth_kept
                self.pub_depth_info.publish(info)
                self.pub_depth.publish(depth_to_msg(depth, stamp_ns, frame_id=optical))
            self.pub.publish(records_to_cloud2(records, stamp_ns, frame_id=frame_id,
                                               organized_shape=(h, w) if organized else None))
            self.count("clouds_published")
            return
        else:  # projective rectification: back-mapping + DLT with the world-frame P
            g = self.geometry
            disp = np.where(np.isfinite(frame.disparity), frame.disparity, np.float32(-1))
            points, colours = cloud_from_disparity(disp, pack_bgr_image(bgr), g.rectification(), g.P_left,
                                                   g.P_right, scale=g.metres_per_unit, mask=mask,
                                                   organized=organized)
            if cloud_frame == "world":
                frame_id = self._world_frame()
            else:
                target = (self._target_frame(cloud_frame) if cloud_frame in ("world_z_up", "parent")
                          else g.frames.get("raw_left", ""))
                points = transform_points(g.lookup(target, g.world_frame), points).astype(np.float32)
                frame_id = target
        self.pub.publish(points_to_cloud2(points, None, stamp_ns=stamp_ns, frame_id=frame_id,
                                          organized=organized, rgb=colours))
        self.count("clouds_published")

    def _depth_wanted(self) -> bool:
        """Whether ``left/depth`` has a reader (over DDS or this process's intra-process bus): the
        depth image (a full frame of float32) is built and sent only then."""
        if self.pub_depth.get_subscription_count() > 0 or self.pub_depth_info.get_subscription_count() > 0:
            return True
        bus = self.intra_process
        return bus is not None and bus.subscription_count(self.pub_depth.topic_name) > 0

    def _target_frame(self, cloud_frame: str) -> str:
        g = self.geometry
        if cloud_frame == "world":
            return g.world_frame
        if cloud_frame == "parent":
            if not g.frames.get("parent"):
                raise CanopyStereoError("cloud_frame parent: rectify_node is mounted on no frame (its "
                                        "parent_frame is empty)")
            return g.frames["parent"]
        z_up = g.frames.get("world_z_up", "")
        if not z_up:
            raise CanopyStereoError("cloud_frame world_z_up: rectify_node publishes no z-up frame "
                                    "(its world_z_up_frame is empty)")
        return z_up


_STREAMS = ("disparity", "colour image", "camera_info", "mask")


def _cloud_frame_problem(value) -> str | None:
    """Why ``value`` is not a ``cloud_frame`` (None when it is one): the one check, at start
    and on every parameter change."""
    if value not in CLOUD_FRAMES:
        return f"cloud_frame must be one of {', '.join(CLOUD_FRAMES)}, got {value!r}"
    return None


def main(args=None) -> int:
    """``ros2 run canopy_stereo point_cloud_node`` (no rig: the geometry comes from rectify_node)."""
    return run_node(PointCloudNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
