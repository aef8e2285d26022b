"""What the viewer shows from ROS: a bag (raw frames through the graph, or recorded outputs), a live graph.

Graph outputs arrive per topic; :class:`FrameStreamer` gathers the messages of
one stamp (``points2``, ``disparity``, ``left/mask``, ``left/image_rect_color``,
``left/camera_info``), converts them and logs the frame from a worker thread
(optionally measuring leaves and canopy first), so that the graph's receiving
thread never waits for the viewer. The logging itself is
:mod:`canopy_stereo.viz.rerun_log` (no ROS).
"""
from __future__ import annotations

import queue
import threading
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.compressed_image import COMPRESSED_SUFFIX, compressed_topic
from canopy_stereo.viz.rerun_log import CameraPose, FrameLogger, camera_pose_from_rig

#: Graph topics (relative to the namespace) a frame is made of.
FRAME_TOPICS = ("points2", "disparity", "left/mask", "left/image_rect_color", "left/camera_info", "left/image_raw")


def measure_frame(frame: dict, *, rig=None):
    """The plant of one decoded graph frame (:func:`decode_frame`: ``raw`` left image,
    ``disparity``; without the raw image the recorded ``mask``) measured by the package's
    one measuring pipeline (:func:`canopy_stereo.ros.measuring.measure_graph_frame`, the
    numbers of ``demo``, ``reconstruct --measure`` and ``batch``). Returns the
    :class:`~canopy_stereo.measure.plant.PlantMeasurement` with its mask and leaf ids carried
    to the rectified grid the viewer draws on, or None when there is nothing to measure or
    no rig to measure with."""
    from dataclasses import replace

    from canopy_stereo.geometry.rig_rectification import rectification_for_rig
    from canopy_stereo.measure.plant import to_rectified_grid
    from canopy_stereo.ros.measuring import measure_graph_frame

    if rig is None or frame.get("disparity") is None or (frame.get("raw") is None and frame.get("mask") is None):
        return None
    try:
        measured = measure_graph_frame(frame.get("raw"), frame["disparity"], rig, mask_rect=frame.get("mask"))
    except CanopyStereoError:
        return None
    rect = rectification_for_rig(rig)  # outlines and mask are drawn over the rectified image
    ids = measured.scene.leaf_ids
    return replace(measured, mask=to_rectified_grid(measured.mask, rig, rect) > 0,
                   scene=replace(measured.scene, leaf_ids=None if ids is None else to_rectified_grid(ids, rig, rect)))


class FrameStreamer:
    """Gathers graph outputs per stamp and logs complete frames to a :class:`FrameLogger`.

    Args:
        logger: where frames go.
        rig: the rig (places the camera in the world), or None (pinhole only).
        need_mask: wait for the plant mask too before a frame is complete.
        need_raw: wait for the raw left image too (measuring a graph run: the plant is found on it).
        measure: measure leaves and canopy of each frame (needs organized clouds and masks).
        drop_when_busy: live use: when the logger is still busy with earlier frames,
            skip frames instead of queueing them (the graph never waits).
        on_logged: optional ``f()`` called after each frame is logged (progress).
    """

    def __init__(self, logger: FrameLogger, rig=None, *, need_mask: bool = True, measure: bool = False,
                 drop_when_busy: bool = False, on_logged=None, need_raw: bool = False):
        self.logger = logger
        self.set_rig(rig)
        self.required = ({"points2", "disparity", "left/image_rect_color"} | ({"left/mask"} if need_mask else set())
                         | ({"left/image_raw"} if need_raw else set()))
        self.measure = measure
        self.pending: dict[int, dict] = {}
        self.lock = threading.Lock()
        self.queue: queue.Queue = queue.Queue(maxsize=2 if drop_when_busy else 0)
        self.drop_when_busy = drop_when_busy
        self.skipped = 0
        self.logged = 0
        self.errors: list[str] = []
        #: (stamp, REPORT.json dict in mm/cm^2/cm^3 or None) of each frame logged, in order
        self.measurements: list[tuple[int, dict | None]] = []
        self.on_logged = on_logged
        self.worker = threading.Thread(target=self._work, name="canopy_viewer", daemon=True)
        self.worker.start()

    def set_rig(self, rig) -> None:
        """The rig of the frames that follow (None: camera pose unknown)."""
        self.rig = rig
        self.pose = None
        if rig is not None:
            try:
                self.pose = camera_pose_from_rig(rig)
            except CanopyStereoError:
                self.pose = None

    # called from the graph's receiving thread
    def on_output(self, rel: str, stamp: int, data: bytes) -> None:
        if rel == "left/image_raw" + COMPRESSED_SUFFIX:  # a compressed recording's raw left image
            from canopy_stereo.ros.compressed import decompress_image_cdr

            rel, data = "left/image_raw", decompress_image_cdr(data)
        if rel not in FRAME_TOPICS or stamp is None:
            return
        done = []
        with self.lock:
            entry = self.pending.setdefault(stamp, {})
            entry[rel] = data
            if self.required <= entry.keys():
                done.append((stamp, self.pending.pop(stamp), self.pose, self.rig))
                for older in sorted(s for s in self.pending if s < stamp):
                    old = self.pending.pop(older)
                    if "points2" in old:
                        done.insert(-1, (older, old, self.pose, self.rig))
        for item in done:
            self._submit(item)

    def _submit(self, item) -> None:
        if self.drop_when_busy:
            try:
                self.queue.put_nowait(item)
            except queue.Full:
                self.skipped += 1
        else:
            self.queue.put(item)

    def close(self, timeout_s: float | None = None) -> None:
        """Log the frames still pending (those with a cloud), then stop the worker (waiting
        for every queued frame unless ``timeout_s``)."""
        with self.lock:
            rest = sorted(self.pending.items())
            self.pending.clear()
        for stamp, entry in rest:
            if "points2" in entry:
                self.queue.put((stamp, entry, self.pose, self.rig))
        self.queue.put(None)
        self.worker.join(timeout_s)

    def _work(self) -> None:
        while True:
            item = self.queue.get()
            if item is None:
                return
            try:
                stamp, entry, pose, rig = item
                self.log_messages(stamp, entry, pose=pose, rig=rig)
            except Exception as exc:  # noqa: BLE001 - a bad frame must not stop the viewer
                self.errors.append(f"{type(exc).__name__}: {exc}")

    def log_messages(self, stamp: int, entry: dict, *, pose: CameraPose | None = None, rig=None) -> None:
        """Decode one stamp's CDR messages (relative topic -> bytes) and log the frame
        (``pose``: of its rectified left camera, default the current rig's)."""
        frame = decode_frame(entry)
        pose = pose if pose is not None else self.pose
        if pose is None and frame.get("K") is not None:
            pose = CameraPose(K=frame["K"], size=frame["size"])
        measured = measure_frame(frame, rig=rig if rig is not None else self.rig) if self.measure else None
        self.measurements.append((stamp, None if measured is None else measured.report))
        self.logger.log_frame(stamp, points_m=frame.get("points"), colors=frame.get("colors"),
                              image_bgr=frame.get("image"), depth_m=frame.get("depth"),
                              mask=frame.get("mask") if measured is None else measured.mask.astype(np.uint8) * 255,
                              camera=pose, measurement=None if measured is None else measured.scene)
        self.logged += 1
        if self.on_logged is not None:
            self.on_logged()


def decode_frame(entry: dict) -> dict:
    """Arrays of one frame's CDR messages (relative topic -> bytes): ``points`` (N, 3) m,
    ``colors``, ``organized`` (H, W, 3) m or None, ``depth`` (H, W) m, ``image`` BGR
    (rectified), ``raw`` BGR (the raw left image), ``mask``, ``K``/``size`` from the camera info."""
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, Image, PointCloud2
    from stereo_msgs.msg import DisparityImage

    from canopy_stereo.ros.convert import cloud2_to_points, msg_to_bgr, msg_to_disparity, msg_to_image

    out: dict = {}
    if "points2" in entry:
        cloud = deserialize_message(entry["points2"], PointCloud2)
        pts, cols = cloud2_to_points(cloud, organized=cloud.height > 1)
        if cloud.height > 1:
            out["organized"] = pts
        out["points"], out["colors"] = pts.reshape(-1, 3), None if cols is None else cols.reshape(-1, 3)
    if "disparity" in entry:
        disp = msg_to_disparity(deserialize_message(entry["disparity"], DisparityImage))
        out["depth"] = disp.depth()
        out["disparity"] = disp
    if "left/image_rect_color" in entry:
        out["image"] = msg_to_bgr(deserialize_message(entry["left/image_rect_color"], Image))
    if "left/image_raw" in entry:
        out["raw"] = msg_to_bgr(deserialize_message(entry["left/image_raw"], Image))
    if "left/mask" in entry:
        out["mask"] = msg_to_image(deserialize_message(entry["left/mask"], Image))
    if "left/camera_info" in entry:
        info = deserialize_message(entry["left/camera_info"], CameraInfo)
        out["K"] = np.asarray(info.k, np.float64).reshape(3, 3)
        out["size"] = (int(info.width), int(info.height))
    return out


def bag_kind(bag) -> tuple[str, str]:
    """``("outputs", namespace)`` for a bag with recorded ``points2``, ``("raw", namespace)``
    for one with ``left/image_raw`` and ``right/image_raw`` (or only their ``/compressed``
    topics); else :class:`CanopyStereoError`."""
    topics = set(bag.topics)
    for t in sorted(topics):
        if t.endswith("/points2"):
            return "outputs", t[: -len("/points2")]
    for suffix in ("", COMPRESSED_SUFFIX):
        for t in sorted(topics):
            left = "/left/image_raw" + suffix
            if t.endswith(left) and t[: -len(left)] + "/right/image_raw" + suffix in topics:
                return "raw", t[: -len(left)]
    raise CanopyStereoError(f"{bag.path} has neither raw stereo frames (<ns>/left/image_raw and "
                            f"<ns>/right/image_raw) nor recorded clouds (<ns>/points2); topics: "
                            f"{', '.join(sorted(topics)) or 'none'}")


def show_recorded_outputs(bag, namespace: str, logger: FrameLogger, *, rig=None, measure: bool = False,
                          measurements: list | None = None) -> int:
    """Log a bag of recorded graph outputs frame by frame (grouped by header stamp); returns
    the number of frames (clouds) logged. ``measurements``: a list extended with the
    ``(stamp, report or None)`` of each frame logged."""
    from canopy_stereo.ros.compressed import decompress_image_cdr
    from canopy_stereo.ros.recorder import header_stamp_from_cdr

    prefix = namespace.rstrip("/") + "/"
    # images recorded compressed (run --record --compress-images) are read from <topic>/compressed
    stored = {rel: prefix + rel if prefix + rel in bag.topics else compressed_topic(prefix + rel)
              for rel in FRAME_TOPICS}
    present = {rel for rel, t in stored.items() if t in bag.topics}
    by_topic = {stored[rel]: rel for rel in present}
    streamer = FrameStreamer(logger, rig, need_mask="left/mask" in present, measure=measure)
    streamer.required = present - {"left/camera_info"}
    for m in bag.messages(list(by_topic)):
        data = decompress_image_cdr(m.data) if m.topic.endswith(COMPRESSED_SUFFIX) else m.data
        streamer.on_output(by_topic[m.topic], header_stamp_from_cdr(m.data), data)
    streamer.close()
    if measurements is not None:
        measurements.extend(streamer.measurements)
    if streamer.errors:
        raise CanopyStereoError(f"{bag.path}: could not show a frame: {streamer.errors[0]}")
    return streamer.logged


def run_raw_bag(path, rig, logger: FrameLogger, *, measure: bool = True, matcher=None,
                domain_id=None, progress=None, on_logged=None):
    """Run a bag of raw frames through the graph (organized clouds, plant masks) and log
    every frame as it comes out; returns the :class:`~canopy_stereo.ros.runner.RunResult`
    with ``viewer_frames`` (frames logged) and ``viewer_measurements`` (``(stamp, report
    or None)`` per frame, by stamp)."""
    from sensor_msgs.msg import Image

    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    streamer = FrameStreamer(logger, rig, need_mask=True, measure=measure, on_logged=on_logged, need_raw=measure)
    options = GraphOptions(matcher=matcher, segment=True, organized=True, parameter_services=False)
    from sensor_msgs.msg import CompressedImage

    extra = {"left/image_rect_color": Image,
             **({"left/image_raw": Image, "left/image_raw" + COMPRESSED_SUFFIX: CompressedImage} if measure else {})}
    try:
        result = run_bag(Path(path), rig, rate=0, options=options, domain_id=domain_id,
                         extra_outputs=extra, on_output=streamer.on_output,
                         progress=progress)
    finally:
        streamer.close()
    if streamer.errors:
        raise CanopyStereoError(f"{path}: could not show a frame: {streamer.errors[0]}")
    result.viewer_frames = streamer.logged
    result.viewer_measurements = sorted(streamer.measurements, key=lambda m: m[0])
    return result


class LiveView:
    """Stream a running graph to a viewer: a native window when there is a display, else the
    web viewer served on localhost (its address printed), kept up after the run until Ctrl-C.

    Pass :attr:`extra_outputs` and :meth:`on_output` to
    :func:`~canopy_stereo.ros.runner.run_bag`; call :meth:`finish` afterwards. Frames the
    viewer cannot keep up with are skipped, never queued: the graph does not wait for it.
    """

    def __init__(self, rig=None, *, name: str = "live", need_mask: bool = True, port: int | None = None,
                 printer=print):
        from sensor_msgs.msg import Image

        from canopy_stereo.viz.rerun_log import has_display, port_free, serve_web

        self.printer = printer
        if port is None:
            port = 9090 if port_free(9090) else None  # else any free port: the address is printed
        self.web = None if has_display() else serve_web(port=port)
        if self.web is not None:
            printer(f"viewer: {self.web.url} (no display here: open it in a browser)")
        self.need_mask = need_mask
        self.extra_outputs = {"left/image_rect_color": Image}
        self.shown = self.skipped = 0
        self.rec = self.streamer = None
        self.start_recording(name, rig)

    def start_recording(self, name: str, rig=None) -> None:
        """A new recording (its own entry in the viewer) for the frames that follow, e.g. the
        next scene of the demo: scenes do not share a timeline or a camera."""
        from canopy_stereo.viz.rerun_log import open_recording

        self._close_recording()
        self.rec = open_recording(web=self.web, spawn=self.web is None, name=name, with_measurements=False)
        self.logger = FrameLogger(self.rec, with_measurements=False)
        self.streamer = FrameStreamer(self.logger, rig, need_mask=self.need_mask, measure=False,
                                      drop_when_busy=True)

    def _close_recording(self) -> None:
        from canopy_stereo.viz.rerun_log import close_recording

        if self.streamer is not None:
            self.streamer.close(timeout_s=120.0)
            self.shown += self.streamer.logged
            self.skipped += self.streamer.skipped
            self.streamer = None
        if self.rec is not None:
            close_recording(self.rec)
            self.rec = None

    def on_output(self, rel: str, stamp: int, data: bytes) -> None:
        self.streamer.on_output(rel, stamp, data)

    def finish(self, *, wait: bool = True) -> None:
        """Log what is pending, close the recording; with a web viewer, serve until Ctrl-C
        (``wait``) and stop it."""
        try:
            self._close_recording()
            self.printer(f"viewer: showed {self.shown} frames"
                         + (f", skipped {self.skipped} while busy" if self.skipped else ""))
            if self.web is not None and wait:
                self.web.serve_until_interrupted()
        finally:
            if self.web is not None:
                self.web.stop()
