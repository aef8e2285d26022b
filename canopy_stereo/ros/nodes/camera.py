"""``camera_node``: one webcam (or a video file / image sequence) -> ``<camera_name>/image_raw``.

Run one per camera, e.g. ``camera_name:=left device:=0`` and
``camera_name:=right device:=1``, or one for a one-device stereo webcam (``layout``).
Frames are published as bgr8 ``sensor_msgs/Image`` on ``<camera_name>/image_raw`` and/or
as JPEG ``sensor_msgs/CompressedImage`` on ``<camera_name>/image_raw/compressed``
(image_transport's topic and format, ``transport``).

* ``transport``: ``raw`` (default), ``compressed`` or ``both``. A device delivering MJPEG
  (``fourcc: MJPG``) with ``compressed`` output publishes the device's own JPEG bytes,
  never decoded (``both``: decoded once for the raw image); files, image sequences and
  the halves of a stereo layout are encoded at ``jpeg_quality`` (1-100, default 95 as
  image_transport's);
* ``layout``: ``mono`` (default), ``side_by_side`` or ``top_bottom``: one capture holding
  both views of a synchronized stereo webcam (left view left / on top) is split into
  ``left/image_raw`` and ``right/image_raw`` (and their compressed topics and
  ``left|right/camera_info``; calibration parameters ``left.camera_info_url``,
  ``right.camera_info_url``, services ``left/set_camera_info``, ``right/set_camera_info``),
  both with one stamp, both in ``frame_id`` (default the left camera's optical frame: one
  frame for a stereo pair, as image_geometry needs); ``camera_name`` then does not apply;
* stamps: the driver's capture time where the backend gives one (V4L2 buffer timestamps,
  ``CAP_PROP_POS_MSEC`` of OpenCV's V4L2 backend, on ``CLOCK_MONOTONIC``), mapped onto
  the ROS clock; else the reception time minus ``stamp_latency`` (s, default 0)
  (:mod:`canopy_stereo.io.capture_stamps`). ``/diagnostics`` reports ``stamp latency ms``
  (capture -> reception, measured with driver times) and ``stamp jitter ms`` (spread of
  the stamp intervals).

Parameters:

* ``device``: V4L2 index (``"0"``), device path (``/dev/video2``), video file or
  image-sequence pattern (``frames/left_%03d.png``, OpenCV numbering);
* ``width``, ``height``, ``fps``, ``fourcc`` (e.g. ``MJPG``): requested capture
  settings (0/empty = the device's default; ``fps`` also paces files);
* ``frame_id`` (default ``left_camera_optical_frame`` for the ``left`` and the ``right`` camera of
  a stereo pair, image_geometry's convention: one frame for both infos, the right camera's pose
  in its ``P`` and ``/tf_static``; ``<camera_name>_camera_optical_frame`` for another name,
  REP 103), ``camera_name`` (``left``);
* ``camera_info_url`` (``file://``, ``package://``, ``${NAME}``, ``${ROS_HOME}``) or the rig
  (``--params-file RIG.yaml`` or ``rig_file``): then ``<camera_name>/camera_info`` is published
  with each frame (REP 104); ``~/set_camera_info`` (``sensor_msgs/srv/SetCameraInfo``) takes a
  new calibration (``cameracalibrator``'s commit) and stores it at the URL
  (:mod:`canopy_stereo.ros.camera_info`);
* ``loop``: restart a file or sequence at its end (otherwise stop there).

* ``open_timeout`` (s, default 5), ``read_timeout`` (s, default 0 = ten frame periods,
  at least 3 s): how long an open or a read may block.

Capture runs on a worker thread (:class:`CaptureSession`), never on the executor:
OpenCV's open and read have no timeout and block indefinitely on a FIFO without a
writer or a stalled device. The executor only supervises, so the node keeps
answering and Ctrl-C/SIGTERM stop it within a second whatever OpenCV does.
When the device disappears (unplugged, read failure), cannot be opened within
``open_timeout`` or stalls for ``read_timeout``, the node logs once, retries to
open it with exponential back-off (0.25 s doubling up to 8 s) and resumes
publishing when it is back; it never exits because of the device.
"""
from __future__ import annotations

import threading
import time

import cv2
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import CompressedImage, Image

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.camera_frames import CAMERA_TRANSPORTS, LAYOUTS, prepare_frame
from canopy_stereo.io.capture_stamps import CaptureClock
from canopy_stereo.io.compressed_image import compressed_topic
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY
from canopy_stereo.ros.camera_info import RawCameraInfoPublisher, default_camera_frame
from canopy_stereo.ros.compressed import compressed_msg
from canopy_stereo.ros.convert import image_to_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node

BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 8.0
#: Seconds an open may take before the source counts as missing (``open_timeout``).
OPEN_TIMEOUT_S = 5.0
#: Default ``read_timeout``: this many frame periods without a frame, at least this many seconds.
READ_TIMEOUT_FRAMES = 10
READ_TIMEOUT_MIN_S = 3.0
#: Period of the supervising timer on the executor (s).
SUPERVISE_PERIOD_S = 0.05
#: Sessions still blocked inside OpenCV after which no new attempt is started.
MAX_BLOCKED_SESSIONS = 2
#: Seconds ``destroy_node`` waits for capture threads to return.
STOP_WAIT_S = 0.2


def is_device(source: str) -> bool:
    """True for a V4L2 index or ``/dev/...`` path, False for files and patterns."""
    return source.strip().isdigit() or source.startswith("/dev/")


def quiet_opencv_warnings() -> None:
    """Keep OpenCV's own warnings (one per read past the end of an image sequence, per
    failed device probe) off the console: the node logs what happened itself."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is not None and hasattr(log, "setLogLevel"):
        log.setLogLevel(log.LOG_LEVEL_ERROR)


def open_capture(source: str, width: int = 0, *, height: int = 0, fps: float = 0.0,
                 fourcc: str = "", device_jpeg: bool = False) -> cv2.VideoCapture | None:
    """An opened ``cv2.VideoCapture`` for ``source`` with the requested settings, or None.
    ``device_jpeg``: a device delivering MJPEG hands over its JPEG bytes undecoded."""
    src = source.strip()
    if src.isdigit():
        cap = cv2.VideoCapture(int(src))
    elif "%" in src:
        cap = cv2.VideoCapture(src, cv2.CAP_IMAGES)
    else:
        cap = cv2.VideoCapture(src)
    if not cap.isOpened():
        cap.release()
        return None
    if is_device(src):
        if fourcc:
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fourcc[:4].ljust(4)))
        if width > 0:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        if height > 0:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        if fps > 0:
            cap.set(cv2.CAP_PROP_FPS, fps)
        if device_jpeg and fourcc.upper().startswith("MJP"):
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    return cap


def driver_time_ns(cap: cv2.VideoCapture) -> int | None:
    """The capture time of the frame just read, as the backend reports it (V4L2: the buffer
    timestamp on CLOCK_MONOTONIC, in ``CAP_PROP_POS_MSEC``), in ns; None when it has none."""
    get = getattr(cap, "get", None)  # a capture-like source may have no properties
    if get is None:
        return None
    try:
        ms = float(get(cv2.CAP_PROP_POS_MSEC))
    except cv2.error:
        return None
    return int(ms * 1e6) if ms > 0 else None


class CaptureSession(threading.Thread):
    """One attempt to use a source: open it, then read frames until told to stop or the
    source ends or fails. Runs on its own daemon thread and is the only code that touches
    its ``cv2.VideoCapture``, so a call that blocks (a FIFO without a writer, a stalled
    V4L2 device: OpenCV has no timeout for either) blocks this thread alone; the node
    abandons the session and the capture is released whenever the call returns.

    ``on_frame(session, frame, stamp_ns) -> bool`` is called for every frame (False: stop);
    the session paces reads at ``period_s`` for files and image sequences.
    ``stamp_now(driver_monotonic_ns)`` stamps a frame as it is received, given the
    device's capture time on ``CLOCK_MONOTONIC`` (ns; None for files and sequences).
    """

    def __init__(self, source: str, settings: dict, on_frame, period_s: float, stamp_now):
        super().__init__(name=f"capture {source}", daemon=True)
        self.source, self.settings, self.on_frame = source, settings, on_frame
        self.period_s = period_s
        self.stamp_now = stamp_now
        self.stop_event = threading.Event()
        self.started_at = time.monotonic()
        self.opened_at: float | None = None    # monotonic time the open returned a capture
        self.last_frame_at: float | None = None
        self.frames = 0
        self.result: str | None = None         # "cannot open", "no frame", "end", "stopped"
        self.error = ""

    def run(self) -> None:
        try:
            cap = open_capture(self.source, **self.settings)
        except Exception as exc:  # noqa: BLE001 - OpenCV raises for some malformed sources
            cap, self.error = None, f"{type(exc).__name__}: {exc}"
        if cap is None:
            self.result = "cannot open"
            return
        self.opened_at = time.monotonic()
        try:
            next_t = time.monotonic()
            while not self.stop_event.is_set():
                ok, frame = cap.read()
                stamp_ns = self.stamp_now(driver_time_ns(cap) if is_device(self.source) and ok else None)
                if self.stop_event.is_set():
                    break
                if not ok or frame is None:
                    self.result = "end" if self.frames > 0 and not is_device(self.source) else "no frame"
                    return
                self.frames += 1
                self.last_frame_at = time.monotonic()
                if not self.on_frame(self, frame, stamp_ns):
                    break
                if not is_device(self.source) and self.period_s > 0:  # files: pace at fps
                    next_t = max(next_t + self.period_s, time.monotonic() - self.period_s)
                    self.stop_event.wait(max(0.0, next_t - time.monotonic()))
            self.result = "stopped"
        except Exception as exc:  # noqa: BLE001 - a failing backend is a lost source
            self.result, self.error = "no frame", f"{type(exc).__name__}: {exc}"
        finally:
            cap.release()


class CameraNode(CanopyNode):
    """Capture on a worker thread, supervised from the executor (see module docstring)."""

    def __init__(self, node_name: str = "camera_node", **kwargs):
        super().__init__(node_name, **kwargs)
        quiet_opencv_warnings()
        self.declare_parameter("device", "0", ParameterDescriptor(
            description="V4L2 index (0), /dev path, video file or image-sequence pattern "
                        "(frames/left_%03d.png)", read_only=True, dynamic_typing=True))
        self.declare_number("width", 0, "requested capture width in pixels (0 = the device's default)",
                            minimum=0, maximum=16384, read_only=True)
        self.declare_number("height", 0, "requested capture height in pixels (0 = the device's default)",
                            minimum=0, maximum=16384, read_only=True)
        self.declare_number("fps", 30.0, "frames per second: requested from a device, and the pace "
                            "of the capture loop (files and sequences too)",
                            minimum=0.0, maximum=1000.0, read_only=True)
        self.declare_text("fourcc", "", "requested pixel format, e.g. MJPG (empty = the device's default)",
                          read_only=True)
        self.declare_text("camera_name", "left", "camera name: images go to <camera_name>/image_raw",
                          read_only=True)
        self.declare_text("frame_id", "", "frame_id of the images and camera_info (empty = "
                          "left_camera_optical_frame for left and right, one frame for a stereo pair as "
                          "image_geometry requires; else <camera_name>_camera_optical_frame)",
                          read_only=True)
        self.declare_flag("loop", True, "restart a video file or image sequence at its end",
                          read_only=True)
        self.declare_number("open_timeout", OPEN_TIMEOUT_S, "seconds an open may take before the "
                            "source counts as missing", minimum=0.1, maximum=600.0, read_only=True)
        self.declare_text("transport", "raw", "what is published: raw (<name>/image_raw), compressed "
                          "(<name>/image_raw/compressed, JPEG: the device's own MJPEG bytes when it "
                          "delivers MJPEG) or both", choices=CAMERA_TRANSPORTS, read_only=True)
        self.declare_number("jpeg_quality", DEFAULT_JPEG_QUALITY, "JPEG quality (1-100) of the compressed "
                            "frames encoded here (files, sequences, split stereo frames)",
                            minimum=1, maximum=100, read_only=True)
        self.declare_text("layout", "mono", "mono (one camera) or one device with both views: "
                          "side_by_side (left view in the left half) or top_bottom (left on top), "
                          "split into left/ and right/ topics with one stamp", choices=LAYOUTS,
                          read_only=True)
        self.declare_number("stamp_latency", 0.0, "seconds between capture and reception subtracted "
                            "from the reception time when the driver gives no capture time",
                            minimum=0.0, maximum=10.0, read_only=True)
        self.declare_number("read_timeout", 0.0, "seconds without a frame before an open source counts "
                            f"as stalled; 0 = max({READ_TIMEOUT_MIN_S:g} s, {READ_TIMEOUT_FRAMES} frame periods)",
                            minimum=0.0, maximum=600.0, read_only=True)
        self.source = str(self.get_parameter("device").value)
        self.camera_name = self.get_parameter("camera_name").value
        self.frame_id = self.get_parameter("frame_id").value or default_camera_frame(self.camera_name)
        self.settings = dict(width=int(self.get_parameter("width").value),
                             height=int(self.get_parameter("height").value),
                             fps=float(self.get_parameter("fps").value),
                             fourcc=str(self.get_parameter("fourcc").value))
        self.loop = bool(self.get_parameter("loop").value)
        fps = self.settings["fps"] if self.settings["fps"] > 0 else 30.0
        self.period_s = 1.0 / fps
        self.open_timeout_s = float(self.get_parameter("open_timeout").value)
        read_timeout = float(self.get_parameter("read_timeout").value)
        self.read_timeout_s = read_timeout if read_timeout > 0 else max(READ_TIMEOUT_MIN_S,
                                                                        READ_TIMEOUT_FRAMES * self.period_s)
        if not self.open_timeout_s > 0:
            raise CanopyStereoError(f"open_timeout must be > 0 s, got {self.open_timeout_s}")
        self.transport = str(self.get_parameter("transport").value)
        self.layout = str(self.get_parameter("layout").value)
        self.jpeg_quality = int(self.get_parameter("jpeg_quality").value)
        for name, value, choices in (("transport", self.transport, CAMERA_TRANSPORTS),
                                     ("layout", self.layout, LAYOUTS)):
            if value not in choices:
                raise CanopyStereoError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
        self.clock = CaptureClock(latency_s=float(self.get_parameter("stamp_latency").value))
        self.settings["device_jpeg"] = self.transport == "compressed" and self.layout == "mono"
        sides = [self.camera_name] if self.layout == "mono" else ["left", "right"]
        # a stereo pair's images and infos share one frame (image_geometry; i.e. the left camera's)
        pair_frame = str(self.get_parameter("frame_id").value) or default_camera_frame("left")
        self.frame_ids = [self.frame_id] if self.layout == "mono" else [pair_frame, pair_frame]
        self.pubs = [self.make_publisher(Image, f"{side}/image_raw") if self.transport != "compressed" else None
                     for side in sides]
        self.pubs_compressed = [self.make_publisher(CompressedImage, compressed_topic(f"{side}/image_raw"))
                                if self.transport != "raw" else None for side in sides]
        self.pub = self.pubs[0]
        # <side>/camera_info with a rig
        self.infos = [RawCameraInfoPublisher(self, side, of_pair=self.layout != "mono") for side in sides]
        self.info = self.infos[0]
        self.session: CaptureSession | None = None
        self.abandoned: list[CaptureSession] = []  # sessions still blocked inside OpenCV
        self.backoff = BACKOFF_START_S
        self.next_attempt = 0.0
        self.lost_logged = False
        self.reported_open = False
        self.finished = False
        self._publish_lock = threading.Lock()
        self._stamp_source = ""
        self._stopping = False
        self.timer = self.create_timer(SUPERVISE_PERIOD_S, self.guarded(self._supervise))

    def _hardware_id(self) -> str:
        return str(self.get_parameter("device").value) if self.has_parameter("device") else ""

    # ------------------------------------------------------------------ worker side
    def _on_frame(self, session: CaptureSession, frame, stamp_ns: int) -> bool:
        """Publish one captured frame (called on the session's thread); False stops the session."""
        try:
            views = prepare_frame(np.asarray(frame), layout=self.layout, transport=self.transport,
                                  quality=self.jpeg_quality)
        except CanopyStereoError as exc:
            self.drop(str(exc), "captured frame")
            return True
        msgs = []
        for v in views:
            frame_id = self.frame_ids[v.side]
            raw = None if v.image is None else image_to_msg(v.image, "bgr8", stamp_ns=stamp_ns, frame_id=frame_id)
            jpeg = None if v.compressed is None else compressed_msg(v.compressed[1], v.compressed[0],
                                                                   stamp_ns=stamp_ns, frame_id=frame_id)
            msgs.append((v, frame_id, raw, jpeg))
        with self._publish_lock:
            if self._stopping or session is not self.session:
                return False
            for v, frame_id, raw, jpeg in msgs:
                if raw is not None:
                    self.pubs[v.side].publish(raw)
                if jpeg is not None:
                    self.pubs_compressed[v.side].publish(jpeg)
                self.infos[v.side].publish(stamp_ns, frame_id, v.shape)
        self.count("frames_published")
        return True

    def _stamp_now(self, driver_monotonic_ns: int | None = None) -> int:
        """The frame's stamp: the driver's capture time on the ROS clock, else the reception
        time minus ``stamp_latency`` (:class:`~canopy_stereo.io.capture_stamps.CaptureClock`)."""
        receive_ns, mono_ns = self.get_clock().now().nanoseconds, time.monotonic_ns()
        out = self.clock.stamp(receive_ns=receive_ns, receive_monotonic_ns=mono_ns,
                               driver_monotonic_ns=driver_monotonic_ns)
        if out.source != self._stamp_source:
            self._stamp_source = out.source
            self.get_logger().info(f"camera {self.camera_name}: stamps from "
                                   + ("the driver's capture times" if out.source == "driver" else
                                      f"the reception time minus {self.clock.latency_ns / 1e6:g} ms"))
        if out.latency_ms is not None:
            self.diagnostics.sample("stamp latency ms", out.latency_ms)
        jitter = self.clock.jitter_ms
        if jitter is not None:
            self.diagnostics.sample("stamp jitter ms", jitter)
        return out.stamp_ns

    # ------------------------------------------------------------------ executor side
    def _supervise(self) -> None:
        """Start, watch and replace capture sessions; never blocks."""
        self.abandoned = [s for s in self.abandoned if s.is_alive()]
        s = self.session
        if s is not None:
            now = time.monotonic()
            if s.result is None and s.opened_at is None and now - s.started_at > self.open_timeout_s:
                self._abandon(s)
                self._lost(f"opening {self.source} did not finish within {self.open_timeout_s:g} s")
            elif s.result is None and s.opened_at is not None and \
                    now - (s.last_frame_at or s.opened_at) > self.read_timeout_s:
                self._abandon(s)
                self._lost(f"{self.source} stalled: no frame for {self.read_timeout_s:g} s")
            elif s.result is not None:
                self._session_ended(s)
            elif s.frames > 0 and s.opened_at is not None:
                self._opened(s)
            return
        if self.finished or time.monotonic() < self.next_attempt:
            return
        if len(self.abandoned) >= MAX_BLOCKED_SESSIONS:
            return  # earlier attempts still hang inside OpenCV: do not pile up threads
        self.session = CaptureSession(self.source, self.settings, self._on_frame, self.period_s, self._stamp_now)
        self.reported_open = False
        self.session.start()

    def _opened(self, s: CaptureSession) -> None:
        if self.reported_open:
            return
        self.reported_open = True
        if self.lost_logged:
            self.get_logger().info(f"camera {self.camera_name}: {self.source} is back")
        elif self.counts["opened"] == 0:
            self.get_logger().info(f"camera {self.camera_name}: opened {self.source}")
        self.count("opened")
        self.lost_logged = False
        self.backoff = BACKOFF_START_S

    def _session_ended(self, s: CaptureSession) -> None:
        self.session = None
        if s.frames > 0:
            self._opened(s)
        if s.result == "end":
            if self.loop:
                self.next_attempt = 0.0  # end of file: start again at once
                return
            self.get_logger().info(f"camera {self.camera_name}: end of {self.source}")
            self.finished = True
        elif s.result == "cannot open":
            self._lost(f"cannot open {self.source}" + (f" ({s.error})" if s.error else ""))
        elif s.result == "no frame":
            self._lost(f"no frame from {self.source}" + (f" ({s.error})" if s.error else ""))

    def _abandon(self, s: CaptureSession) -> None:
        s.stop_event.set()
        with self._publish_lock:  # no frame of an abandoned session is published after this
            self.session = None
        self.abandoned.append(s)
        self.count("stalls")

    def _lost(self, reason: str) -> None:
        if not self.lost_logged:
            self.get_logger().warning(f"camera {self.camera_name}: {reason}; retrying with back-off")
            self.lost_logged = True
        self.count("open_failures")
        self.next_attempt = time.monotonic() + self.backoff
        self.backoff = min(BACKOFF_MAX_S, self.backoff * 2)

    def destroy_node(self):
        """Stop publishing at once; a session blocked inside OpenCV is left to its daemon
        thread (it releases its capture when the call returns, or dies with the process)."""
        with self._publish_lock:
            self._stopping = True
        sessions = [s for s in [self.session, *self.abandoned] if s is not None]
        for s in sessions:
            s.stop_event.set()
        deadline = time.monotonic() + STOP_WAIT_S
        for s in sessions:
            s.join(timeout=max(0.0, deadline - time.monotonic()))
        self.session = None
        return super().destroy_node()


def main(args=None) -> int:
    """``ros2 run canopy_stereo camera_node --ros-args -p camera_name:=left -p device:=0``."""
    return run_node(CameraNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
