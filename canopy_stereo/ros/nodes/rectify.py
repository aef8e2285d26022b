"""``rectify_node``: pair raw left/right frames by approximate time, undistort and rectify.

The one node that holds the rig (camera matrices as parameters: the rig file).
Subscribes ``left/image_raw`` and ``right/image_raw`` (``sensor_msgs/Image``,
bgr8/rgb8/mono8/bgra8/rgba8 of the rig's image size), or with ``image_transport:
compressed`` (image_transport's convention, the parameter stereo_image_proc has)
``left/image_raw/compressed`` and ``right/image_raw/compressed``
(``sensor_msgs/CompressedImage``, JPEG or PNG in any ``format`` drivers write:
:mod:`canopy_stereo.io.image_codec`; each frame decoded once, a corrupt one dropped
with its reason; REP 2003 sensor-data QoS, see :mod:`canopy_stereo.ros.qos`). Publishes, with the left
frame's stamp:

* ``left/image_rect``, ``right/image_rect``: mono8 rectified images;
* ``left/image_rect_color``: bgr8 rectified left image;
* ``left/image_rect/camera_info``, ``right/image_rect/camera_info``: the rectified
  cameras (REP 104: ``D = 0``, ``R = I``, ``P = [K | (Tx, 0, 0)]``, ``Tx = -f B`` for the
  right one, one principal point for both), both in the LEFT rectified optical frame
  (``frame_id``), as the right rectified image: image_geometry's ``StereoCameraModel``
  asserts one frame for the pair (``right_frame_id`` overrides it). They sit
  beside their images, away from ``left/camera_info``, which is the *raw* camera's
  (a camera driver's, e.g. ``camera_node``). A Hartley rectification is projective
  and has no metric camera: its infos are the uncalibrated ones (size only, zero
  matrices);
* ``stereo_geometry`` (latched): what a ``CameraInfo`` cannot carry
  (:mod:`canopy_stereo.ros.stereo_geometry`);
* ``/tf_static`` (latched, when tf2_msgs is importable and ``publish_tf`` is true):
  ``canopy_world_z_up -> canopy_world -> {left,right}_camera_optical_frame,
  {left,right}_camera_rect_optical_frame``; mounted (``parent_frame`` set):
  ``parent_frame -> canopy_world -> {the cameras, canopy_world_z_up}``.

Mounting on a robot (REP 105): ``parent_frame`` (the robot frame carrying the rig, e.g.
``base_link`` or ``tool0``; "" = the world frame is a root), ``mount`` (seven numbers
``x y z qx qy qz qw``, metres: the rig's world frame in ``parent_frame``) or instead
``camera_mount`` (seven numbers: the raw left camera's optical frame in ``parent_frame``,
as a hand-eye calibration gives it), ``publish_tf`` (false when the robot's URDF and
robot_state_publisher already own the camera frames: then nothing goes to ``/tf_static``;
``stereo_geometry`` still carries the rig's transforms), ``frame_prefix`` (prepended to
every frame the rig names, e.g. ``rig_a/``, so that two rigs share one TF tree).

Parameters: the rig (:mod:`canopy_stereo.ros.params`), or ``use_camera_info`` (true: the rig
from the drivers' ``left/camera_info`` and ``right/camera_info``, as image_pipeline takes it;
frames before both arrive are dropped; :mod:`canopy_stereo.ros.camera_info_rig`),
``method`` (empty = the rig's),
``H_left``/``H_right`` (unset = the rig's; the rectification is
:func:`~canopy_stereo.geometry.rig_rectification.rectification_for_rig`'s), ``fps`` (the
cameras' frame rate, 0 = measured from the stamps), ``sync_slop`` (s; -1 = half a frame
period at ``fps``), ``queue_size``,
``frame_id`` (rectified left optical frame) and ``right_frame_id`` ("" = ``frame_id`` in the
messages, ``right_camera_rect_optical_frame`` in the transforms), ``world_frame``,
``world_z_up_frame`` ("" = none), ``image_transport`` (``raw``/``compressed``),
``left_camera_frame``/``right_camera_frame`` (raw optical frames in the transforms),
``zero_stamps``, ``max_stamp_gap``, the mounting parameters above, ``skew_compensation``,
``waiting_pairs``, ``follow_matcher``,
``reliability``, ``diagnostic_period``.

Skew compensation (``skew_compensation``, default true): free-running webcams capture
up to half a frame apart; each pair's right image is brought to the left image's
instant (the pair's stamp) along the right camera's own motion between its previous
and current frame (:class:`~canopy_stereo.skew.SkewCompensator`); the shift is composed
into the right camera's rectification map, so the right image (grey from the start: its
only output is mono) is resampled once. ``/diagnostics`` reports ``skew ms`` (right minus left stamp),
``skew compensated %`` (share of the pairs that needed it: a still scene needs none),
``skew shift px`` and ``skew compensation ms`` (the time it adds), and ``skew not compensated:
<reason>`` (first frame, a cut, too little texture, ...; those pairs go on as they came, logged
once per reason).

Stamps that go back further than the pairing tolerance (a looping bag, a
restarted driver) reset the pairing with one log line; pairing goes on.

Stamps that make no sense (:mod:`canopy_stereo.ros.stamps`): a zero stamp is restamped with
the receive time (``zero_stamps: restamp``, the default) or dropped (``drop``), a warning on
``/diagnostics`` either way; a stamp repeated by the driver is dropped as ``duplicate stamp``
(and its gap not counted as lost); ``max_stamp_gap`` (s, 0 = off) warns about stamps that far
from the receive time, naming the gap.

A slow rectification never backs up the input queues (at 1280x720 a pair can take longer
than a frame period): the callbacks only check stamps and pair the frames' messages; one
worker decodes, rectifies and publishes the newest complete pair, at most ``waiting_pairs``
(1) wait while it is busy and older ones are dropped as ``camera pair: superseded``. So a
rectified pair leaves at most one pair's work after its frames arrived, where a node that
works through its keep-last queue in order falls ``queue_size`` frames behind.

Paced by the matcher (``follow_matcher``, default true): rectifying pairs that
``disparity_node`` then skips as superseded is wasted work (at 1280x720 half the pairs, a
quarter of two cores). ``disparity_node`` publishes ``disparity/matching`` (``std_msgs/Header``)
as it takes each pair; while the last pair this node published has not been taken, the worker
waits (at most :data:`MATCHER_WAIT_S`) and then rectifies the newest pair. Without a publisher
on ``disparity/matching`` (another matcher, or none), or while the matcher takes a pair about every
frame period (median take interval at most :data:`KEEPS_UP_PERIODS` periods: waiting would only
delay the pairs), every pair is rectified. For a slower matcher the worker also starts the next
pair just in time (:func:`matcher_start_delay`): rectified right after the take, it would wait in
the matcher's queue for the whole match while newer frames come. The match time comes from the
matcher (``disparity/matched``: the stamp of each pair it is done with), not from the intervals
between takes, which a late start would lengthen.

Frames that never reached the node (overwritten in its keep-last input queue while it
was busy, or lost upstream) are counted as drops (``left frame: missed ...``, in
``/diagnostics``): a gap of ``k`` frame periods between two left stamps (the period
measured from the stamps, median of recent intervals) is ``k - 1`` missed frames; gaps
longer than 2 s are pauses, not losses.
"""
from __future__ import annotations

import array
import threading
import time
from collections import deque
from dataclasses import replace

import cv2
import numpy as np
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from std_msgs.msg import Header, String

from canopy_stereo.bag.pairing import ApproximateTimePairer, FramePeriodEstimator, slop_for_rate
from canopy_stereo.geometry.frames import (
    DEFAULT_FRAMES,
    WORLD_FRAME,
    WORLD_Z_UP_FRAME,
    FrameNames,
    prefixed_frames,
    stereo_info_frame,
    stereo_transforms,
)
from canopy_stereo.geometry.rectification import StereoRectifier
from canopy_stereo.io.images import to_gray
from canopy_stereo.ros.compressed import TRANSPORTS, compressed_msg_to_bgr, input_topic
from canopy_stereo.ros.convert import (
    COLOUR_ENCODINGS,
    image_to_msg,
    make_header,
    msg_to_bgr,
    msg_to_mono,
    rectified_camera_info,
    stamp_to_ns,
    uncalibrated_camera_info,
)
from canopy_stereo.ros.limits import check_image_msg
from canopy_stereo.ros.mounting import declare_mount_parameters, mount_from_node
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rectification_from_node, rig_from_node
from canopy_stereo.ros.stereo_geometry import STEREO_GEOMETRY_TOPIC, stereo_geometry_msg
from canopy_stereo.ros.tf import StaticTransformPublisher, latched_qos
from canopy_stereo.skew import SkewCompensator

#: ``disparity_node``'s pacing topic: the stamp of each pair as its matcher takes it.
MATCHING_TOPIC = "disparity/matching"
#: ``disparity_node``'s pacing topic: the stamp of each pair as its matcher is done with it.
MATCHED_TOPIC = "disparity/matched"
#: Longest wait (s) for the matcher to take the last published pair (``follow_matcher``).
MATCHER_WAIT_S = 0.25
#: ``follow_matcher`` waits only for a matcher slower than this many frame periods per pair
#: (the median of its last :data:`TAKE_INTERVALS` take intervals).
KEEPS_UP_PERIODS = 1.5
TAKE_INTERVALS = 8
#: A pair started just in time is ready this long (s) before the matcher is expected to be done
#: (the transport of its images, the spread of match times).
START_MARGIN_S = 0.02


def matcher_start_delay(*, since_take_s: float, match_s: float, work_s: float,
                        margin_s: float = START_MARGIN_S) -> float:
    """How long (s, >= 0) to wait before rectifying the next pair when the matcher took the
    last one ``since_take_s`` ago and takes ``match_s`` per pair, and rectifying and publishing
    a pair takes this node ``work_s``: the pair is then ready ``margin_s`` before the matcher
    is free, the newest pair of that moment instead of one that waited in the matcher's queue
    for the whole match. 0 when that moment has passed."""
    return max(0.0, match_s - work_s - margin_s - since_take_s)

#: Rectified CameraInfo topics (beside their images; ``<side>/camera_info`` is the raw camera's).
RECT_INFO_TOPICS = ("left/image_rect/camera_info", "right/image_rect/camera_info")

_FRAME_PARAMETERS = {
    "frame_id": (DEFAULT_FRAMES[("rect", "left")], "optical frame of the rectified left camera "
                 "(rectified images, disparity, depth)"),
    "right_frame_id": ("", "frame of the right rectified image and camera_info ('' = frame_id: "
                       "image_geometry needs one frame for a stereo pair; the right camera's own "
                       f"frame is {DEFAULT_FRAMES[('rect', 'right')]} in /tf_static)"),
    "world_frame": (WORLD_FRAME, "the rig's world frame (the frame of the rig file's P, in metres)"),
    "world_z_up_frame": (WORLD_Z_UP_FRAME, "z-up view of the world frame for RViz ('' = none)"),
    "left_camera_frame": (DEFAULT_FRAMES[("raw", "left")], "optical frame of the raw left camera"),
    "right_camera_frame": (DEFAULT_FRAMES[("raw", "right")], "optical frame of the raw right camera"),
}

#: Pairing tolerance (s) while the frame rate is neither given nor measured yet: half a
#: period at 30 frames/s, the fastest common webcam rate.
INITIAL_SLOP_S = slop_for_rate(30.0)

#: Drop reason of frames that never arrived (see the module docstring).
MISSED_REASON = "missed (overwritten in the input queue while the node was busy, or lost upstream)"
#: Longest gap between two left frames (s) still counted as lost frames rather than a pause.
MISSED_MAX_GAP_S = 2.0


class RectifyNode(CanopyNode):
    """Approximate-time pairing + rectification (see module docstring)."""

    def __init__(self, node_name: str = "rectify_node", **kwargs):
        super().__init__(node_name, **kwargs)
        declare_rig_parameters(self)
        self.declare_number("fps", 0.0, "frame rate of the cameras (frames/s); sets the pairing "
                            "tolerance when sync_slop is -1; 0 = measured from the stamps",
                            minimum=0.0, maximum=1000.0, read_only=True)
        self.declare_number("sync_slop", -1.0, "largest stamp difference of a left/right pair (s); "
                            "-1 = half a frame period (from fps, or measured)",
                            minimum=-1.0, maximum=10.0, read_only=True)
        self.declare_number("queue_size", 5, "frames per camera kept while waiting for a partner",
                            minimum=1, maximum=100, read_only=True)
        self.declare_number("waiting_pairs", 1, "complete pairs kept waiting while the node rectifies; when "
                            "more arrive the oldest is dropped (the newest win, latency stays bounded)",
                            minimum=1, maximum=100, read_only=True)
        for name, (default, desc) in _FRAME_PARAMETERS.items():
            self.declare_text(name, default, desc, read_only=True)
        self.declare_text("image_transport", "raw", "input transport: raw (<side>/image_raw, Image) or "
                          "compressed (<side>/image_raw/compressed, CompressedImage: JPEG/PNG)",
                          choices=TRANSPORTS, read_only=True)
        self.transport = str(self.get_parameter("image_transport").value)
        self.declare_flag("skew_compensation", True, "bring each pair's right image to the left image's "
                          "instant along the right camera's motion (free-running cameras on a moving rig "
                          "or in wind)", read_only=True)
        self.skew = SkewCompensator(enabled=bool(self.get_parameter("skew_compensation").value))
        self._skew_reasons_logged: set[str] = set()
        self.rectifying = self.latest_only(self._rectify_pair, "camera pair",
                                           depth=int(self.get_parameter("waiting_pairs").value))
        self.declare_flag("follow_matcher", True, "rectify a pair only once disparity_node has taken the last "
                          "one published (its disparity/matching stamps; every pair without that topic): no "
                          "work on pairs the matcher would skip", read_only=True)
        self._matcher = threading.Condition()
        self._published_ns: int | None = None  # the last pair published
        self._taken_ns: int | None = None  # the last pair the matcher took
        self._matcher_silent = False  # a wait timed out and no take came since: do not wait
        self._match_times: deque[float] = deque(maxlen=TAKE_INTERVALS)  # s from a take to its "matched"
        self._takes: deque[tuple[int, float]] = deque(maxlen=TAKE_INTERVALS + 1)  # (stamp ns, monotonic s)
        self._work_times: deque[float] = deque(maxlen=TAKE_INTERVALS)  # s per rectified pair (the worker's)
        self._frame_period_s: float | None = None  # the cameras' frame period, measured from the stamps
        follow = bool(self.get_parameter("follow_matcher").value)
        self.sub_matching = self.make_subscription(Header, MATCHING_TOPIC, self._on_matching) if follow else None
        self.sub_matched = self.make_subscription(Header, MATCHED_TOPIC, self._on_matched) if follow else None
        self.declare_flag("use_camera_info", False, "take the rig from the drivers' left/camera_info and "
                          "right/camera_info (REP 104, as image_pipeline does) instead of a rig file",
                          read_only=True)
        declare_mount_parameters(self)
        self.rig = None
        p = {name: str(self.get_parameter(name).value) for name in _FRAME_PARAMETERS}
        self.mounting = mount_from_node(self)
        self.frames = prefixed_frames(FrameNames(
            world=p["world_frame"], world_z_up=p["world_z_up_frame"], raw_left=p["left_camera_frame"],
            raw_right=p["right_camera_frame"], rect_left=p["frame_id"],
            rect_right=p["right_frame_id"] or DEFAULT_FRAMES[("rect", "right")],
            parent=self.mounting.parent_frame), self.mounting.frame_prefix)
        self.frame_id = self.frames.rect_left
        #: frame ids of the left and right rectified messages (one, unless right_frame_id is set)
        self.message_frames = (self.frame_id, self.frames.rect_right if p["right_frame_id"]
                               else stereo_info_frame(self.frames, "rect"))
        slop = float(self.get_parameter("sync_slop").value)
        fps = float(self.get_parameter("fps").value)
        # sync_slop >= 0 is fixed; otherwise half a frame period, measured unless fps is given
        self.period_estimator = FramePeriodEstimator() if slop < 0 and fps <= 0 else None
        if slop < 0:
            slop = slop_for_rate(fps) if fps > 0 else INITIAL_SLOP_S
        self.stamp_check = self.declare_stamp_checks(2)  # zero, duplicate, far-off stamps
        self.left_gaps = FramePeriodEstimator(1, max_interval_s=MISSED_MAX_GAP_S)
        self._last_left_ns = None
        self.pairer = ApproximateTimePairer(slop, int(self.get_parameter("queue_size").value),
                                            on_jump=self.time_jump_handler(("left", "right")))
        self.pub_left = self.make_publisher(Image, "left/image_rect")
        self.pub_right = self.make_publisher(Image, "right/image_rect")
        self.pub_color = self.make_publisher(Image, "left/image_rect_color")
        self._message_buffers: dict[str, array.array] = {}  # topic -> its image messages' data
        self.pub_info_left = self.make_publisher(CameraInfo, RECT_INFO_TOPICS[0])
        self.pub_info_right = self.make_publisher(CameraInfo, RECT_INFO_TOPICS[1])
        self.pub_geometry = self.create_publisher(String, STEREO_GEOMETRY_TOPIC, latched_qos())
        #: the rig's transform tree ``[(parent, child, T_parent_child)]`` (metres), mount included,
        #: and what of it goes to /tf_static and into recordings (nothing when the robot owns the
        #: frames); empty until the rig is known
        self.transforms: list = []
        self.tf_transforms: list = []
        if self.get_parameter("use_camera_info").value:
            from canopy_stereo.ros.camera_info_rig import CameraInfoRig

            self._subscribe()
            self.camera_info_rig = CameraInfoRig(self, self.guarded(self._use_rig))
            self.get_logger().info("waiting for left/camera_info and right/camera_info (the rig)")
        else:
            self._use_rig(rig_from_node(self))  # warmed up on the rig's size, then subscribed
            self._subscribe()

    def _subscribe(self) -> None:
        """The camera image subscriptions (with the middleware's receive time, for zero stamps).
        Compressed frames (30-160 kB) cross processes best effort without loss on Fast DDS
        (benchmarks/bench_transport_qos.py), raw ones (0.9 MB) do not: REP 2003's sensor-data
        QoS for compressed input, which also matches best-effort drivers."""
        in_type, packed = (Image, False) if self.transport == "raw" else (CompressedImage, True)
        self.sub_left = self.make_subscription(in_type, input_topic("left/image_raw", self.transport),
                                               lambda m, i: self._on_image(0, m, i), sensor_data=packed,
                                               with_info=True)
        self.sub_right = self.make_subscription(in_type, input_topic("right/image_raw", self.transport),
                                                lambda m, i: self._on_image(1, m, i), sensor_data=packed,
                                                with_info=True)

    def _use_rig(self, rig) -> None:
        """Rectify with ``rig`` from now on; publish its geometry and static transforms (latched)."""
        self.rect = rectification_from_node(self, rig)
        self.rectifier = StereoRectifier(rig, self.rect)
        self.rig = rig
        self.transforms = stereo_transforms(self.rig, self.rect, names=self.frames,
                                            mount=self.mounting.transform(rig))
        self.pub_geometry.publish(stereo_geometry_msg(self.rig, self.rect, self.frames,
                                                      transforms=self.transforms))
        self.tf_transforms = self.transforms if self.mounting.publish_tf else []
        self.tf_static = StaticTransformPublisher(self, self.tf_transforms)
        if self.rect.method != "fusiello":
            self.get_logger().info("hartley rectification: the rectified camera_info is uncalibrated "
                                   "(a projective rectification has no metric camera)")
        if not self.mounting.publish_tf:
            self.get_logger().info("publish_tf is false: no /tf_static (the robot's URDF owns the frames "
                                   f"{', '.join(c for _, c, _ in self.transforms)})")
        elif not self.tf_static.available:
            self.get_logger().info("tf2_msgs is not installed: no /tf_static (the transforms are on "
                                   f"{STEREO_GEOMETRY_TOPIC} and in recorded bags)")
        w, h = self.rig.image_size
        self.warm_up(f"rectification of {w}x{h} pairs", self._warm_up)
        self.get_logger().info(f"rectifying {w}x{h} pairs ({self.rect.method}), "
                               f"sync slop {self.pairer.slop_ns / 1e9:g} s"
                               + (" until the frame period is measured" if self.period_estimator else ""))

    def _to_image(self, side: int, msg) -> np.ndarray:
        """An input frame (raw or compressed, decoded once), checked against the rig's size:
        uint8 BGR (H, W, 3) for the left camera (``left/image_rect_color``), uint8 grey (H, W)
        for the right one, whose only output is mono (a JPEG decoded straight to grey)."""
        size = self.rig.image_size
        if isinstance(msg, CompressedImage):
            return compressed_msg_to_bgr(msg, expected_size=size, grey=side == 1)
        check_image_msg(msg, expected_size=size, encodings=COLOUR_ENCODINGS)
        return msg_to_bgr(msg, expected_size=size) if side == 0 else msg_to_mono(msg, expected_size=size)

    def _on_image(self, side: int, msg, info: dict | None = None) -> None:
        """One camera frame: stamp checks and pairing of the message (raw frames checked for
        size and encoding first); a complete pair goes to the worker (:meth:`_rectify_pair`)."""
        name = ("left", "right")[side]
        self.count(f"{name}_received")
        if self.rig is None:
            self.drop("no rig yet (waiting for left/camera_info and right/camera_info)", f"{name} frame")
            return
        if isinstance(msg, Image):
            try:
                check_image_msg(msg, expected_size=self.rig.image_size, encodings=COLOUR_ENCODINGS)
            except Exception as exc:
                self.drop(str(exc), f"{name} frame")
                return
        stamp = self.checked_stamp(self.stamp_check, side, stamp_to_ns(msg.header.stamp), f"{name} frame",
                                   info=info)
        if stamp is None:  # a duplicate, or a zero stamp with zero_stamps: drop
            return
        if side == 0:
            self._count_missed(stamp)
        if self.period_estimator is not None:
            self._follow_frame_rate(self.period_estimator.observe(side, stamp))
        pair, dropped = self.pairer.push(side, stamp, msg)
        self.drop_unpaired(dropped, ("left frame", "right frame"))
        if pair is not None:
            self.diagnostics.sample("pair offset ms", pair.skew_ns / 1e6)
            self.count("pairs_complete")
            self.rectifying.submit(pair)

    def _rectify_pair(self, pair) -> None:
        """The worker's job: decode one pair's messages, rectify and publish them; a frame that
        cannot be decoded drops the pair, naming the reason for it and its partner."""
        if not self._matcher_ready():
            self.drop("superseded by newer ones while the node was busy", "camera pair")
            return
        t0 = time.monotonic()
        images = []
        for side, msg in enumerate(pair.items):
            try:
                images.append(self._to_image(side, msg))
            except Exception as exc:
                name, other = ("left", "right")[side], ("right", "left")[side]
                self.drop(str(exc), f"{name} frame")
                self.drop(f"its {name} frame was dropped", f"{other} frame")
                return
        left, right = images
        self._publish(pair.stamps_ns[0], left, self._rectified_right(right, pair.stamps_ns))
        self._work_times.append(time.monotonic() - t0)

    def _on_matching(self, msg) -> None:
        """``disparity/matching``: the matcher took the pair stamped ``msg.stamp``."""
        now = time.monotonic()
        with self._matcher:
            self._taken_ns = stamp_to_ns(msg.stamp)
            self._matcher_silent = False
            self._takes.append((self._taken_ns, now))
            self._matcher.notify_all()

    def _on_matched(self, msg) -> None:
        """``disparity/matched``: the matcher is done with the pair stamped ``msg.stamp``; the
        time since its take is a match time (both messages a few bytes: their transport cancels).
        The next pair's take may come first (the matcher takes it at once): takes are looked up
        by stamp."""
        now, stamp = time.monotonic(), stamp_to_ns(msg.stamp)
        with self._matcher:
            took = next((t for s, t in reversed(self._takes) if s == stamp), None)
            if took is not None:
                self._match_times.append(now - took)

    def _matcher_keeps_up(self) -> bool:
        """True when the matcher takes a pair about every frame period (median of its last
        :data:`TAKE_INTERVALS` take intervals at most :data:`KEEPS_UP_PERIODS` frame periods):
        then waiting for it would only delay pairs (each would wait for a take that comes
        anyway), so the node rectifies every pair."""
        with self._matcher:
            times = [t for _, t in self._takes]
        period = self._frame_period_s
        if period is None or len(times) <= TAKE_INTERVALS:
            return False
        return float(np.median(np.diff(times))) <= KEEPS_UP_PERIODS * period

    def _start_just_in_time(self, deadline: float) -> None:
        """Once the matcher took the last pair: wait (until ``deadline`` at most, monotonic s)
        for the moment from which this node's work on the next pair ends just before the
        matcher is done (:func:`matcher_start_delay`, from the medians of the recent match times
        and of this node's times per pair); at once while either is unknown."""
        with self._matcher:
            if not self._takes or not self._match_times or not self._work_times:
                return
            delay = matcher_start_delay(since_take_s=time.monotonic() - self._takes[-1][1],
                                        match_s=float(np.median(self._match_times)),
                                        work_s=float(np.median(self._work_times)))
            if delay <= 0:
                return
            self.diagnostics.sample("start delay ms", delay * 1e3)
            self.count("pairs_started_just_in_time")
            until = min(deadline, time.monotonic() + delay)
            while (remaining := until - time.monotonic()) > 0:
                self._matcher.wait(remaining)

    def _matcher_ready(self) -> bool:
        """Wait (at most :data:`MATCHER_WAIT_S`) until the matcher has taken the last pair
        published; False when a newer pair came meanwhile and fills the waiting places
        (``waiting_pairs``): the worker takes that one instead. A pair not taken in that time
        (lost, a restarted matcher, or one warming up) is not waited for again, and no pair is
        until the matcher takes one (a looping bag would otherwise freeze on one frame: each
        wait times out, and the same frame of the next pass comes again)."""
        if self.sub_matching is None or self.sub_matching.get_publisher_count() == 0 or self._matcher_keeps_up():
            return True
        t0 = time.monotonic()
        deadline = t0 + MATCHER_WAIT_S
        taken = True
        with self._matcher:
            while (not self._matcher_silent and self._published_ns is not None
                   and (self._taken_ns is None or self._taken_ns < self._published_ns)):
                remaining = deadline - time.monotonic()
                if remaining <= 0:  # lost, or a matcher that takes nothing (warming up): no more waits until it does
                    self._published_ns, taken, self._matcher_silent = None, False, True
                    break
                self._matcher.wait(remaining)
        if taken:
            self._start_just_in_time(deadline)
        waited_s = time.monotonic() - t0
        if waited_s > 1e-3:
            self.diagnostics.sample("matcher wait ms", waited_s * 1e3)
        return self.rectifying.waiting() < self.rectifying.depth

    def _rectified_right(self, right: np.ndarray, stamps_ns: tuple[int, int]) -> np.ndarray:
        """A pair's right image (grey, ``stamps_ns``: the left and right stamps), rectified: at
        the left image's instant when the skew compensation can (its shift composed into the
        rectification map: one interpolation), else as it came, saying why; reported on
        ``/diagnostics``."""
        t0 = time.perf_counter()
        shift, rep = self.skew.measure(right, stamp_left_ns=stamps_ns[0], stamp_right_ns=stamps_ns[1])
        if shift is None:
            self._report_skew(rep)
            return self.rectifier.rectify_one(right, "right", copy=False)
        rectified = shift.apply(right, coords=self.rectifier.coordinates("right"))
        self._report_skew(replace(rep, cost_ms=1e3 * (time.perf_counter() - t0)))
        return rectified

    def _report_skew(self, rep) -> None:
        """One pair's :class:`~canopy_stereo.skew.SkewReport` on ``/diagnostics`` (and a log
        line once per reason it was not compensated)."""
        d = self.diagnostics
        d.sample("skew ms", rep.skew_ms)
        if rep.reason in ("off", "in step", "still"):  # nothing to compensate
            return
        d.sample("skew compensated %", 100.0 if rep.applied else 0.0)
        if rep.applied:
            d.sample("skew shift px", rep.shift_px)
            d.sample("skew compensation ms", rep.cost_ms)
            self.count("pairs_skew_compensated")
            return
        kind = rep.reason.split(":")[0].split(" (")[0]
        kind = "gap" if kind.startswith("gap of") else "skew longer than a frame" if "longer than" in kind else kind
        d.note(f"skew not compensated: {kind}")
        if kind not in self._skew_reasons_logged:  # once per kind: a first frame per stream is normal
            self._skew_reasons_logged.add(kind)
            self.get_logger().info(f"pair with {rep.skew_ms:.1f} ms skew not compensated: {rep.reason} "
                                   "(paired as it came)")

    def _warm_up(self) -> None:
        """One pair of the rig's size through conversion and rectification, nothing published."""
        w, h = self.rig.image_size
        frame = np.random.default_rng(0).integers(0, 256, (h, w, 3), dtype=np.uint8)
        msg = image_to_msg(frame, "bgr8", stamp_ns=1, frame_id="")
        left_r = self.rectifier.rectify_one(self._to_image(0, msg), "left")
        grey = self._to_image(1, msg)
        image_to_msg(left_r, "bgr8", stamp_ns=1, frame_id="")
        image_to_msg(to_gray(left_r), "mono8", stamp_ns=1, frame_id="")
        image_to_msg(self.rectifier.rectify_one(grey, "right"), "mono8", stamp_ns=1, frame_id="")
        if self.skew.enabled:  # the optical flow's first call (its own compensator: no state kept)
            warm = SkewCompensator(flow_scale=self.skew.flow_scale, flow_preset=self.skew.flow_preset)
            for k in (1, 2):
                shift, _ = warm.measure(grey, stamp_left_ns=k * 66_000_000, stamp_right_ns=k * 66_000_000 + 8_000_000)
            if shift is not None:
                shift.apply(grey, coords=self.rectifier.coordinates("right"))

    def _count_missed(self, stamp_ns: int) -> None:
        """Count the left frames missing between the previous left stamp and ``stamp_ns``."""
        period_s = self.left_gaps.observe(0, stamp_ns)
        if period_s is not None:
            self._frame_period_s = period_s
        last, self._last_left_ns = self._last_left_ns, stamp_ns
        duplicates = self.stamp_check.take_duplicates(0)  # sent, with a repeated stamp: not lost
        if period_s is None or last is None:
            return
        gap_s = (stamp_ns - last) / 1e9
        if gap_s <= 1.5 * period_s or gap_s > MISSED_MAX_GAP_S:
            return
        for _ in range(int(round(gap_s / period_s)) - 1 - duplicates):
            self.drop(MISSED_REASON, "left frame")

    def camera_infos(self, stamp_ns: int) -> tuple[CameraInfo, CameraInfo]:
        """The rectified ``CameraInfo`` pair stamped ``stamp_ns``."""
        fl, fr = self.message_frames
        if self.rect.K_rect_left is None:
            return (uncalibrated_camera_info(self.rect.size, stamp_ns, frame_id=fl),
                    uncalibrated_camera_info(self.rect.size, stamp_ns, frame_id=fr))
        baseline_m = self.rect.baseline * self.rig.metres_per_unit
        return (rectified_camera_info(self.rect.K_rect_left, self.rect.size, baseline_m, "left",
                                      stamp_ns=stamp_ns, frame_id=fl),
                rectified_camera_info(self.rect.K_rect_right, self.rect.size, baseline_m, "right",
                                      stamp_ns=stamp_ns, frame_id=fr))

    def _follow_frame_rate(self, period_s: float | None) -> None:
        """Pairing tolerance = half the measured frame period (updated when it moves > 10 %)."""
        if period_s is None:
            return
        slop = 0.5 * period_s
        current = self.pairer.slop_ns / 1e9
        if abs(slop - current) > 0.1 * current:
            self.pairer.set_slop(slop)
            self.get_logger().info(f"frame period {period_s * 1e3:.1f} ms measured from the stamps: "
                                   f"pairing tolerance {slop * 1e3:.1f} ms")

    def _subscribed(self, pub) -> bool:
        """Whether anyone takes ``pub``'s messages (a DDS subscription, or one on the
        intra-process bus): image_pipeline's lazy outputs, an image nobody reads is not built."""
        if pub.get_subscription_count() > 0:
            return True
        return self.intra_process is not None and self.intra_process.subscription_count(pub.topic_name) > 0

    def _image_message(self, pub, encoding: str, shape: tuple[int, ...], stamp_ns: int,
                       frame_id: str) -> tuple[Image, np.ndarray]:
        """An ``Image`` for ``pub`` and a writable uint8 view of ``shape`` on its data: the
        rectified image is written straight into the message (no copy between the remap and
        the publisher). rclpy serialises a message inside ``publish``, so each topic reuses
        its buffer frame after frame; a topic with subscriptions on the intra-process bus
        (which hands over the message object itself) gets a new one every time."""
        n = int(np.prod(shape))
        shared = self.intra_process is not None and self.intra_process.subscription_count(pub.topic_name) > 0
        buf = None if shared else self._message_buffers.get(pub.topic_name)
        if buf is None or len(buf) != n:
            buf = array.array("B", bytes(n))
            if not shared:
                self._message_buffers[pub.topic_name] = buf
        # check_fields: the setter keeps an array.array('B') as it is (else it copies it)
        msg = Image(header=make_header(stamp_ns, frame_id), height=shape[0], width=shape[1],
                    encoding=encoding, is_bigendian=0, step=n // shape[0], check_fields=True)
        msg.data = buf
        return msg, np.frombuffer(buf, np.uint8).reshape(shape)

    def _publish(self, stamp_ns: int, left: np.ndarray, right_r: np.ndarray) -> None:
        """Rectify ``left`` (uint8 BGR, raw) and publish the pair with ``right_r`` (uint8 grey
        (H, W), rectified): the camera infos always, each image when it is subscribed, each
        written into its message's buffer."""
        info_l, info_r = self.camera_infos(stamp_ns)
        self.pub_info_left.publish(info_l)
        self.pub_info_right.publish(info_r)
        fl, fr = self.message_frames
        h, w = right_r.shape
        colour = None
        if self._subscribed(self.pub_color):
            colour, view = self._image_message(self.pub_color, "bgr8", (h, w, 3), stamp_ns, fl)
            left_r = self.rectifier.rectify_one(left, "left", out=view)
        else:
            left_r = self.rectifier.rectify_one(left, "left", copy=False)
        if colour is not None:
            self.pub_color.publish(colour)
        sent_left = self._subscribed(self.pub_left)
        if sent_left:
            mono, view = self._image_message(self.pub_left, "mono8", (h, w), stamp_ns, fl)
            cv2.cvtColor(left_r, cv2.COLOR_BGR2GRAY, dst=view)
            self.pub_left.publish(mono)
        sent_right = self._subscribed(self.pub_right)
        if sent_right:
            mono, view = self._image_message(self.pub_right, "mono8", (h, w), stamp_ns, fr)
            np.copyto(view, right_r)
            self.pub_right.publish(mono)
        if sent_left and sent_right:  # a pair the matcher can take (else the next pair must not wait for it)
            with self._matcher:
                self._published_ns = stamp_ns
        self.count("pairs_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo rectify_node --ros-args --params-file RIG.yaml``."""
    return run_node(RectifyNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
