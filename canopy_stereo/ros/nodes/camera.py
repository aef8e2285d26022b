"""``camera_node``: one webcam (or a video file / image sequence) -> ``<camera_name>/image_raw``.

Run one per camera, e.g. ``camera_name:=left device:=0`` and
``camera_name:=right device:=1``. Frames are published as bgr8
``sensor_msgs/Image`` stamped with the node clock right after capture.

Parameters:

* ``device``: V4L2 index (``"0"``), device path (``/dev/video2``), video file or
  image-sequence pattern (``frames/left_%03d.png``, OpenCV numbering);
* ``width``, ``height``, ``fps``, ``fourcc`` (e.g. ``MJPG``): requested capture
  settings (0/empty = the device's default; ``fps`` also paces files);
* ``frame_id`` (default ``<camera_name>_camera_optical_frame``, REP 103), ``camera_name`` (``left``);
* the rig (``--params-file RIG.yaml`` or ``rig_file``): then ``<camera_name>/camera_info``
  is published with each frame (REP 104, :mod:`canopy_stereo.ros.camera_info`);
* ``loop``: restart a file or sequence at its end (otherwise stop there).

When the device disappears (unplugged, read failure) the node logs once,
retries to open it with exponential back-off (0.25 s doubling up to 8 s) and
resumes publishing when it is back; it never exits because of the device.
"""
from __future__ import annotations

import time

import cv2
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor
from sensor_msgs.msg import Image

from canopy_stereo.ros.camera_info import RawCameraInfoPublisher
from canopy_stereo.ros.convert import image_to_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node

BACKOFF_START_S = 0.25
BACKOFF_MAX_S = 8.0


def is_device(source: str) -> bool:
    """True for a V4L2 index or ``/dev/...`` path, False for files and patterns."""
    return source.strip().isdigit() or source.startswith("/dev/")


def quiet_opencv_warnings() -> None:
    """Keep OpenCV's own warnings (one per read past the end of an image sequence, per
    failed device probe) off the console: the node logs what happened itself."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is not None and hasattr(log, "setLogLevel"):
        log.setLogLevel(log.LOG_LEVEL_ERROR)


def open_capture(source: str, width: int = 0, height: int = 0, fps: float = 0.0,
                 fourcc: str = "") -> cv2.VideoCapture | None:
    """An opened ``cv2.VideoCapture`` for ``source`` with the requested settings, or None."""
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
    return cap


class CameraNode(CanopyNode):
    """Capture loop driven by a timer at ``fps`` (see module docstring)."""

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
        self.declare_text("frame_id", "", "frame_id of the images (empty = <camera_name>_camera)",
                          read_only=True)
        self.declare_flag("loop", True, "restart a video file or image sequence at its end",
                          read_only=True)
        self.source = str(self.get_parameter("device").value)
        self.camera_name = self.get_parameter("camera_name").value
        self.frame_id = self.get_parameter("frame_id").value or f"{self.camera_name}_camera_optical_frame"
        self.settings = dict(width=int(self.get_parameter("width").value),
                             height=int(self.get_parameter("height").value),
                             fps=float(self.get_parameter("fps").value),
                             fourcc=str(self.get_parameter("fourcc").value))
        self.loop = bool(self.get_parameter("loop").value)
        self.pub = self.make_publisher(Image, f"{self.camera_name}/image_raw")
        self.info = RawCameraInfoPublisher(self, self.camera_name)  # <name>/camera_info with a rig
        self.cap = None
        self.backoff = BACKOFF_START_S
        self.next_attempt = 0.0
        self.lost_logged = False
        self.frames_since_open = 0
        self.finished = False
        fps = self.settings["fps"] if self.settings["fps"] > 0 else 30.0
        self.timer = self.create_timer(1.0 / fps, self.guarded(self._tick))

    def _hardware_id(self) -> str:
        return str(self.get_parameter("device").value) if self.has_parameter("device") else ""

    def _try_open(self) -> bool:
        now = time.monotonic()
        if now < self.next_attempt:
            return False
        self.cap = open_capture(self.source, **self.settings)
        if self.cap is None:
            self._lost(f"cannot open {self.source}")
            return False
        if self.lost_logged:
            self.get_logger().info(f"camera {self.camera_name}: {self.source} is back")
        elif self.counts["opened"] == 0:
            self.get_logger().info(f"camera {self.camera_name}: opened {self.source}")
        self.count("opened")
        self.lost_logged = False
        self.backoff = BACKOFF_START_S
        self.frames_since_open = 0
        return True

    def _lost(self, reason: str) -> None:
        if not self.lost_logged:
            self.get_logger().warning(f"camera {self.camera_name}: {reason}; retrying with back-off")
            self.lost_logged = True
        self.count("open_failures")
        self.next_attempt = time.monotonic() + self.backoff
        self.backoff = min(BACKOFF_MAX_S, self.backoff * 2)

    def _tick(self) -> None:
        if self.finished or (self.cap is None and not self._try_open()):
            return
        ok, frame = self.cap.read()
        stamp_ns = self.get_clock().now().nanoseconds
        if not ok or frame is None:
            self.cap.release()
            self.cap = None
            if not is_device(self.source) and self.frames_since_open > 0:
                if self.loop:
                    self.next_attempt = 0.0  # end of file: start again at once
                    return
                self.get_logger().info(f"camera {self.camera_name}: end of {self.source}")
                self.finished = True
                return
            self._lost(f"no frame from {self.source}")
            return
        self.frames_since_open += 1
        if frame.ndim == 2:
            frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
        self.pub.publish(image_to_msg(np.ascontiguousarray(frame[..., :3]), "bgr8", stamp_ns, self.frame_id))
        self.info.publish(stamp_ns, self.frame_id, frame.shape)
        self.count("frames_published")

    def destroy_node(self):
        if self.cap is not None:
            self.cap.release()
            self.cap = None
        return super().destroy_node()


def main(args=None) -> int:
    """``ros2 run canopy_stereo camera_node --ros-args -p camera_name:=left -p device:=0``."""
    return run_node(CameraNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
