"""Logging canopy_stereo frames to Rerun (numpy in; no ROS import).

Entities (all lengths in metres, the world frame of the rig, REP 103 units):

* ``world``: the rig's world frame (``ViewCoordinates`` right-handed, Y down, as the
  rigs' calibration boards define it).
* ``world/cloud``: the coloured point cloud (``Points3D``).
* ``world/camera``: the rectified left camera: its pose (``Transform3D``, world
  from camera) and ``Pinhole`` (rectified intrinsics, RDF optical frame, REP 103),
  so that every image below it lines up with the cloud in the 3D view.
* ``world/camera/image``: the left rectified image; ``world/camera/depth``: depth
  along the optical axis (``DepthImage``, metres); ``world/camera/mask``: the
  plant mask (``SegmentationImage``, 1 = plant); ``world/camera/leaves``: leaf
  outlines with their length x width.
* ``world/leaves``: each measured leaf's length and width lines (3D) with labels;
  ``world/canopy``: the canopy's box in its measuring frame, labelled with
  height x width x depth; ``measurements/*``: scalars over time (canopy
  height, width, depth, hull volume, leaf count).

Every frame is logged on the ``stamp`` timeline (the ROS header stamp).
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.clouds import check_cloud
from canopy_stereo.viz import INSTALL_HINT

#: Timeline of every logged frame (ROS header stamps).
TIMELINE = "stamp"

#: Application id of every recording.
APPLICATION_ID = "canopy_stereo"

CLOUD = "world/cloud"
CAMERA = "world/camera"
IMAGE = "world/camera/image"
DEPTH = "world/camera/depth"
MASK = "world/camera/mask"
LEAF_OUTLINES = "world/camera/leaves"
LEAVES = "world/leaves"
CANOPY = "world/canopy"
MEASUREMENTS = "measurements"

#: Class ids of the mask's segmentation image.
MASK_CLASSES = ((0, "background", (0, 0, 0, 0)), (1, "plant", (255, 0, 200, 255)))

#: Largest number of points logged per cloud (uniform subsample beyond; the viewer stays fluid).
MAX_CLOUD_POINTS = 400_000


def import_rerun():
    """``rerun`` or :class:`CanopyStereoError` with the install hint."""
    try:
        import rerun as rr
    except ImportError:
        raise CanopyStereoError(INSTALL_HINT) from None
    return rr


@dataclass
class CameraPose:
    """The rectified left camera of a frame.

    Attributes:
        K: (3, 3) rectified intrinsics (pixels).
        size: ``(width, height)`` of the rectified image.
        R: (3, 3) world-to-camera rotation (None: pose unknown).
        C_m: (3,) camera centre in the world frame, metres (None: pose unknown).
    """

    K: np.ndarray
    size: tuple[int, int]
    R: np.ndarray | None = None
    C_m: np.ndarray | None = None


def camera_pose_from_rig(rig, rect=None) -> CameraPose:
    """The rectified left camera of ``rig`` (Fusiello rectification unless ``rect`` is
    given): ``P_rect_left = K [R | -R C]`` with ``C`` converted to metres."""
    from canopy_stereo.geometry.camera import decompose_projection
    from canopy_stereo.geometry.rectification import fusiello_rectify

    if rect is None:
        rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    if rect.P_rect_left is None:
        raise CanopyStereoError(f"the {rect.method} rectification has no rectified camera matrix; "
                                "the viewer cannot place the image in the world")
    cam = decompose_projection(rect.P_rect_left)
    return CameraPose(K=cam.K, size=tuple(int(v) for v in rect.size), R=cam.R,
                      C_m=np.asarray(cam.C, np.float64) * rig.metres_per_unit)


def _rotation_quaternion(R: np.ndarray) -> np.ndarray:
    """xyzw quaternion of a proper rotation matrix."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.asarray(R, np.float64)).as_quat()


def blueprint(*, with_measurements: bool = True, camera: CameraPose | None = None):
    """The saved layout: the 3D cloud (left, large; seen from just behind the rectified left
    camera when its pose is known); the rectified image with the mask and leaf outlines
    over it, and the depth (right, stacked); the canopy measurements over time (bottom)."""
    import rerun.blueprint as rrb

    eye = None
    if camera is not None and camera.R is not None and camera.C_m is not None:
        R = np.asarray(camera.R, np.float64)
        C = np.asarray(camera.C_m, np.float64)
        forward, down = R[2], R[1]  # the optical axis and image-down, in the world
        eye = rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, position=C - 0.15 * forward - 0.05 * down,
                                look_target=C + 0.6 * forward, eye_up=-down)
    right = [rrb.Spatial2DView(origin=CAMERA, name="left rectified + plant mask + leaves",
                               contents=["$origin/image", "$origin/mask", "$origin/leaves"]),
             rrb.Spatial2DView(origin=CAMERA, name="depth (m)", contents=["$origin/depth"])]
    # the camera's images are left out of the 3D view (its frustum stays): back-projected,
    # the depth would be a second cloud, and the image plane would hide the cloud behind it
    view3d = rrb.Spatial3DView(origin="world", name="cloud (world frame, m)",
                               contents=["+ $origin/**"] + [f"- /{e}" for e in (IMAGE, DEPTH, MASK, LEAF_OUTLINES)],
                               eye_controls=eye)
    top = rrb.Horizontal(view3d, rrb.Vertical(*right), column_shares=[3, 2])
    body = top
    if with_measurements:
        body = rrb.Vertical(top, rrb.TimeSeriesView(origin=MEASUREMENTS, name="canopy measurements"),
                            row_shares=[4, 1])
    return rrb.Blueprint(body, rrb.BlueprintPanel(state="collapsed"),
                         rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="collapsed"))


class FrameLogger:
    """Logs frames to one Rerun recording (see the module docstring for the entities).

    Args:
        recording: a ``rerun.RecordingStream`` (its sink set by :func:`open_recording`).
    """

    def __init__(self, recording, *, with_measurements: bool = True):
        self.rr = import_rerun()
        self.rec = recording
        self.with_measurements = with_measurements
        self.frames = 0
        self._camera_logged = None
        rr = self.rr
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Y_DOWN, static=True)
        rec.log(CAMERA, rr.AnnotationContext([rr.AnnotationInfo(id=i, label=name, color=colour)
                                              for i, name, colour in MASK_CLASSES]), static=True)

    def set_time(self, stamp_ns: int) -> None:
        self.rec.set_time(TIMELINE, timestamp=np.datetime64(int(stamp_ns), "ns"))

    def log_camera(self, camera: CameraPose) -> None:
        """Pinhole (and pose, when known) of the rectified left camera; static when unchanged."""
        rr = self.rr
        key = (camera.K.tobytes(), camera.size, None if camera.R is None else camera.R.tobytes(),
               None if camera.C_m is None else np.asarray(camera.C_m).tobytes())
        if key == self._camera_logged:
            return
        self._camera_logged = key
        self.rec.log(CAMERA, rr.Pinhole(image_from_camera=camera.K, resolution=list(camera.size),
                                        camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.1),
                     static=True)
        if camera.R is not None and camera.C_m is not None:
            # world from camera: rotation R^T, translation C
            self.rec.log(CAMERA, rr.Transform3D(translation=np.asarray(camera.C_m, np.float64),
                                                mat3x3=np.asarray(camera.R, np.float64).T), static=True)
            # the layout again, now looking at the scene from the camera
            self.rec.send_blueprint(blueprint(with_measurements=self.with_measurements, camera=camera))

    def log_frame(self, stamp_ns: int, *, points_m=None, colors=None, image_bgr=None, depth_m=None,
                  mask=None, camera: CameraPose | None = None, measurement=None) -> None:
        """Log one frame at ``stamp_ns``.

        Args:
            points_m: (N, 3) (or (H, W, 3) organized, NaN = none) world points, metres.
            colors: uint8 RGB of the same leading shape, or None.
            image_bgr: (Hr, Wr, 3) uint8 left rectified image (BGR, OpenCV order).
            depth_m: (Hr, Wr) float depth along the rectified left optical axis, metres (NaN = none).
            mask: (Hr, Wr) plant mask (nonzero = plant).
            camera: the rectified left camera (pinhole, pose).
            measurement: a :class:`~canopy_stereo.measure.SceneMeasurement` in millimetres
                (leaves, canopy box), or None.
        """
        rr = self.rr
        rec = self.rec
        self.set_time(stamp_ns)
        if camera is not None:
            self.log_camera(camera)
        if points_m is not None:
            pts = check_cloud(points_m, organized=None, name="points", dtype=np.float32).reshape(-1, 3)
            cols = None if colors is None else np.asarray(colors, np.uint8).reshape(-1, 3)
            ok = np.all(np.isfinite(pts), axis=1)
            pts = pts[ok]
            cols = None if cols is None else cols[ok]
            if len(pts) > MAX_CLOUD_POINTS:
                keep = np.linspace(0, len(pts) - 1, MAX_CLOUD_POINTS).astype(np.int64)
                pts = pts[keep]
                cols = None if cols is None else cols[keep]
            extent = float(np.linalg.norm(np.ptp(pts, axis=0))) if len(pts) else 1.0
            rec.log(CLOUD, rr.Points3D(pts, colors=cols, radii=max(extent * 1e-3, 1e-5)))
        if image_bgr is not None:
            img = np.asarray(image_bgr)
            rec.log(IMAGE, rr.Image(img, color_model="BGR" if img.ndim == 3 else "L"))
        if depth_m is not None:
            from canopy_stereo.viz.colour import COLORMAP_NAME, colour_range

            z = np.asarray(depth_m, np.float32)
            ok = np.isfinite(z) & (z > 0)
            lo, hi = colour_range(np.where(ok, z, np.nan))  # the package's map and range
            z = np.where(ok, z, 0).astype(np.float32)
            rec.log(DEPTH, rr.DepthImage(z, meter=1.0, colormap=COLORMAP_NAME, depth_range=[lo, hi]))
        if mask is not None:
            rec.log(MASK, rr.SegmentationImage((np.asarray(mask) > 0).astype(np.uint8), opacity=0.35,
                                               draw_order=10.0))
        if measurement is not None:
            self.log_measurement(measurement)
        self.frames += 1

    def log_measurement(self, measurement, unit_to_m: float = 1e-3) -> None:
        """Leaves (3D length/width lines, 2D outlines) and the canopy box of a
        :class:`~canopy_stereo.measure.SceneMeasurement` whose lengths are in the
        unit ``unit_to_m`` metres (default millimetres); labels in millimetres."""
        rr = self.rr
        rec = self.rec
        report = measurement.report
        to_mm = unit_to_m * 1e3
        strips, labels, centres = [], [], []
        for leaf in report.get("leaves", []):
            ends = np.asarray(leaf["ends"], np.float64) * unit_to_m
            width_ends = np.asarray(leaf["width_ends"], np.float64) * unit_to_m
            strips += [ends, width_ends]
            text = f"leaf {leaf['id']}: {leaf['length'] * to_mm:.0f} x {leaf['width'] * to_mm:.0f} mm"
            labels += [text, ""]
            centres.append(np.asarray(leaf["centroid"], np.float64) * unit_to_m)
        if strips:
            rec.log(LEAVES, rr.LineStrips3D(strips, labels=labels,
                                            colors=[(255, 220, 0), (0, 200, 255)] * (len(strips) // 2)))
        else:
            rec.log(LEAVES, rr.Clear(recursive=False))
        if measurement.leaf_ids is not None:
            self._log_leaf_outlines(measurement.leaf_ids, report, to_mm)
        canopy = report.get("canopy") or {}
        frame = measurement.frame
        if canopy and "bbox_min" in canopy:
            lo = np.asarray(canopy["bbox_min"], np.float64)
            hi = np.asarray(canopy["bbox_max"], np.float64)
            axes = np.asarray(frame.axes, np.float64)
            R = axes.T  # world from frame
            if np.linalg.det(R) < 0:  # mirror the y axis so that the rotation is proper
                R = R.copy()
                R[:, 1] *= -1
                lo[1], hi[1] = -hi[1], -lo[1]
            centre_w = (np.asarray(frame.origin, np.float64) + R @ ((lo + hi) / 2)) * unit_to_m
            half = (hi - lo) / 2 * unit_to_m
            label = (f"canopy h {canopy['height'] * to_mm:.0f} x w {canopy['width'] * to_mm:.0f} "
                     f"x d {canopy['depth'] * to_mm:.0f} mm")
            rec.log(CANOPY, rr.Boxes3D(centers=[centre_w], half_sizes=[half],
                                       quaternions=[rr.Quaternion(xyzw=_rotation_quaternion(R))],
                                       labels=[label], colors=[(255, 80, 200)]))
            for name in ("height", "width", "depth"):
                rec.log(f"{MEASUREMENTS}/{name}_mm", rr.Scalars(canopy[name] * to_mm))
            if canopy.get("hull_volume") is not None:  # the package's one unit set: volumes in cm^3
                rec.log(f"{MEASUREMENTS}/hull_volume_cm3", rr.Scalars(canopy["hull_volume"] * to_mm ** 3 / 1000.0))
            rec.log(f"{MEASUREMENTS}/leaves", rr.Scalars(float(canopy.get("n_leaves", 0))))

    def _log_leaf_outlines(self, leaf_ids: np.ndarray, report: dict, to_mm: float) -> None:
        import cv2

        rr = self.rr
        sizes = {leaf["id"]: leaf for leaf in report.get("leaves", [])}
        strips, labels = [], []
        ids = np.asarray(leaf_ids)
        for value in np.unique(ids[ids != 0]):
            leaf = sizes.get(int(value))
            if leaf is None:
                continue
            contours, _ = cv2.findContours((ids == value).astype(np.uint8), cv2.RETR_EXTERNAL,
                                           cv2.CHAIN_APPROX_SIMPLE)
            if not contours:
                continue
            c = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(np.float32)
            strips.append(np.vstack([c, c[:1]]))
            labels.append(f"{leaf['length'] * to_mm:.0f} x {leaf['width'] * to_mm:.0f} mm")
        if strips:
            self.rec.log(LEAF_OUTLINES, rr.LineStrips2D(strips, labels=labels, colors=(255, 220, 0)))
        else:
            self.rec.log(LEAF_OUTLINES, rr.Clear(recursive=False))


# --------------------------------------------------------------------------- sinks


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _wait_listening(host: str, port: int, timeout_s: float, proc=None) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        try:
            with socket.create_connection((host, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.1)
    return False


def _die_with_parent():
    """Child-side: get SIGTERM when the parent dies (Linux), so no viewer server is orphaned."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


@dataclass
class WebViewer:
    """A web viewer (and its gRPC proxy) served by a ``rerun`` child process on localhost.

    Attributes:
        url: the page to open (``http://127.0.0.1:<port>/?url=...``).
        grpc_url: where SDKs log to (``rerun+http://127.0.0.1:<grpc>/proxy``).
        process: the ``rerun --serve-web`` child.
    """

    url: str
    grpc_url: str
    process: subprocess.Popen

    def serve_until_interrupted(self) -> None:
        """Keep serving until Ctrl-C / SIGTERM (or until the server process ends)."""

        def stop(signum, frame):
            raise KeyboardInterrupt

        old = signal.signal(signal.SIGTERM, stop)
        try:
            print(f"serving the viewer at {self.url} (localhost only); Ctrl-C to stop", flush=True)
            while self.process.poll() is None:
                time.sleep(0.2)
        except KeyboardInterrupt:
            pass
        finally:
            signal.signal(signal.SIGTERM, old)

    def stop(self) -> None:
        """Stop the server process."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)


def rerun_command() -> list[str]:
    """The ``rerun`` viewer binary shipped in the rerun-sdk wheel (called directly, not through
    the ``rerun`` console script, which would leave the binary behind when stopped)."""
    import_rerun()
    try:
        import rerun_cli

        exe = os.path.join(os.path.dirname(rerun_cli.__file__), "rerun")
        if os.path.isfile(exe) and os.access(exe, os.X_OK):
            return [exe]
    except ImportError:
        pass
    exe = shutil.which("rerun", path=os.path.dirname(sys.executable) + os.pathsep + os.environ.get("PATH", ""))
    return [exe] if exe else [sys.executable, "-m", "rerun"]


def serve_web(*, port: int | None = None, files=(), host: str = "127.0.0.1",
              timeout_s: float = 30.0, quiet: bool = True) -> WebViewer:
    """Start the web viewer shipped in the rerun-sdk wheel, bound to ``host`` (localhost
    by default: nothing is reachable from other machines unless asked for).

    Args:
        port: HTTP port of the page (default: a free one); the gRPC proxy takes another free port.
        files: ``.rrd`` files the server loads and shows (none: it waits for an SDK to log).
        quiet: send the server's own log to ``/dev/null``.
    """
    from urllib.parse import quote

    web_port = int(port) if port else free_port(host)
    grpc_port = free_port(host)
    cmd = rerun_command() + ["--serve-web", "--bind", host, "--port", str(grpc_port),
                             "--web-viewer-port", str(web_port), "--hide-welcome-screen",
                             *[str(f) for f in files]]
    out = subprocess.DEVNULL if quiet else None
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=out, preexec_fn=_die_with_parent)
    if not (_wait_listening(host, web_port, timeout_s, proc) and _wait_listening(host, grpc_port, timeout_s, proc)):
        proc.terminate()
        proc.wait(10)
        raise CanopyStereoError(f"the Rerun web viewer did not start on {host}:{web_port} "
                                f"(is the port in use? try --port)")
    grpc_url = f"rerun+http://{host}:{grpc_port}/proxy"
    return WebViewer(url=f"http://{host}:{web_port}/?url={quote(grpc_url, safe='')}", grpc_url=grpc_url,
                     process=proc)


def has_display() -> bool:
    """A native viewer window can open (X11 or Wayland)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def open_recording(*, save=None, web: WebViewer | None = None, spawn: bool = False,
                   name: str | None = None, with_measurements: bool = True):
    """A new recording with the canopy blueprint, logging to a file (``save``), to a web
    viewer's proxy (``web``) or to a spawned native viewer (``spawn``)."""
    rr = import_rerun()
    rec = rr.RecordingStream(APPLICATION_ID)
    if name:
        rec.send_recording_name(name)
    bp = blueprint(with_measurements=with_measurements)
    if save is not None:
        rec.save(str(save), default_blueprint=bp)
    elif web is not None:
        rec.connect_grpc(web.grpc_url, default_blueprint=bp)
    elif spawn:
        if not has_display():
            raise CanopyStereoError("no display for a viewer window here: use --web (serve the viewer "
                                    "to a browser) or --save OUT.rrd")
        rec.spawn(default_blueprint=bp)
    return rec


def close_recording(rec, *, timeout_s: float = 120.0) -> None:
    """Flush and close the recording's sink (the .rrd file is complete afterwards); a viewer
    that stopped listening does not hold the caller longer than ``timeout_s``."""
    try:
        rec.flush(timeout_sec=timeout_s)
    finally:
        rec.disconnect()


def port_free(port: int, host: str = "127.0.0.1") -> bool:
    """Nothing listens on ``host:port`` and it can be bound."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, int(port)))
        except OSError:
            return False
    return True
