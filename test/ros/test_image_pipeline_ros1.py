"""Real image_pipeline code on our messages: Debian's ROS 1 builds of stereo_image_proc and
image_proc (the same image_geometry / stereo geometry as ROS 2 Jazzy), run on a recording of
``run --record`` converted with rosbags (``--dst-typestore ros1_noetic``), no field rewritten.

* ``stereo_image_proc/point_cloud2`` (nodelet) on the recorded disparity, rectified left image
  and rectified CameraInfo pair: does not abort (image_geometry asserts one frame for the two
  infos) and its cloud equals our ``points2`` within 1e-6 relative.
* ``image_proc`` on the raw images and the raw CameraInfos a driver (``camera_node``)
  publishes: its ``image_rect`` equals our ``image_rect`` within 1 grey level (median); with
  no lens distortion and ``R != I`` this needs the rectifiable zero-distortion ``D``
  (:data:`canopy_stereo.geometry.frames.ZERO_DISTORTION_RECTIFIABLE`).
* ``stereo_image_proc``'s whole pipeline on the same raw images and infos (both raw infos in
  one ``StereoCameraModel``): no abort, and its block-matching disparities on its own
  rectification agree with our ELAS disparities (median difference under 0.5 px).

Needs apt's ``ros-core python3-rosbag ros-stereo-image-proc ros-image-proc
libstereo-image-proc-dev libimage-proc-dev libnodeletlib-tools`` (``.ci/run`` installs them);
skipped only where apt is not available to install them.
"""
from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.bag import BagReader, BagWriter  # noqa: E402
from canopy_stereo.geometry.frames import raw_camera_calibration  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig  # noqa: E402
from canopy_stereo.ros.graph import GraphOptions  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NODELET = Path("/usr/lib/nodelet/nodelet")
IMAGE_PROC = Path("/usr/lib/image_proc/image_proc")
STEREO_IMAGE_PROC = Path("/usr/lib/stereo_image_proc/stereo_image_proc")
PACKAGES = ("ros-core python3-rosbag ros-stereo-image-proc ros-image-proc python3-image-geometry "
            "libstereo-image-proc-dev libimage-proc-dev libnodeletlib-tools")


def _require_image_pipeline() -> None:
    if all(p.exists() for p in (NODELET, IMAGE_PROC, STEREO_IMAGE_PROC)) and shutil.which("roscore") \
            and shutil.which("rosbag"):
        return
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        pytest.skip("Debian's image_pipeline is not installed and apt is not available here to install it "
                    f"(apt-get install {PACKAGES})")
    pytest.fail(f"Debian's image_pipeline is not installed: apt-get install -y {PACKAGES} (.ci/run does)")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Ros1:
    """A private roscore and the processes started against it (stopped by PID)."""

    def __init__(self, home: Path):
        self.port = _free_port()
        home.mkdir(parents=True, exist_ok=True)
        self.env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "PYTHON", "VIRTUAL_ENV"))}
        self.env["PATH"] = ":".join(p for p in os.environ.get("PATH", "").split(":") if ".venv" not in p)
        self.env.update(ROS_MASTER_URI=f"http://localhost:{self.port}", ROS_HOSTNAME="localhost",
                        ROS_HOME=str(home), ROS_LOG_DIR=str(home / "log"))
        self.procs: list[subprocess.Popen] = []
        self.home = home
        self.start("roscore", ["roscore", "-p", str(self.port)])
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if subprocess.run(["rostopic", "list"], env=self.env, stdin=subprocess.DEVNULL,
                              capture_output=True).returncode == 0:
                return
            time.sleep(0.3)
        raise AssertionError("roscore did not come up")

    def start(self, name, cmd, namespace=None) -> subprocess.Popen:
        env = dict(self.env)
        if namespace:
            env["ROS_NAMESPACE"] = namespace
        with open(self.home / f"{name}.log", "wb") as log:  # the child keeps its own descriptor
            p = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                 start_new_session=True)
        p.name = name
        self.procs.append(p)
        return p

    def run(self, name, cmd, timeout_s: float) -> int:
        """Run ``cmd`` to its end in its own process group (killed whole after ``timeout_s``:
        ``rosbag play`` is a wrapper around the real player)."""
        p = self.start(name, cmd)
        try:
            return p.wait(timeout_s)
        except subprocess.TimeoutExpired:
            self.stop(p, signal.SIGKILL)
            raise AssertionError(f"{name} did not finish in {timeout_s} s:\n{self.log(name)[-2000:]}") from None

    def log(self, name) -> str:
        return (self.home / f"{name}.log").read_text(errors="replace")

    def stop(self, p, sig=signal.SIGINT, timeout=15) -> int | None:
        if p.poll() is None:
            os.killpg(p.pid, sig)
            try:
                p.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
        return p.returncode

    def close(self):
        for p in reversed(self.procs):
            self.stop(p)


def _raw_bag(path: Path, bag: Path, rig) -> Path:
    """The bundled raw images as recorded, with the raw CameraInfo camera_node publishes
    beside each (same stamp and frame: ``RawCameraInfoPublisher``'s message)."""
    cals = {side: raw_camera_calibration(rig, side) for side in ("left", "right")}
    with BagWriter(path) as out:
        for m, msg in BagReader(bag).read(["/stereo/left/image_raw", "/stereo/right/image_raw"]):
            side = m.topic.split("/")[2]
            out.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
            info = convert.camera_info_msg(cals[side], convert.stamp_to_ns(msg.header.stamp),
                                           frame_id=msg.header.frame_id)
            out.write(f"/stereo/{side}/camera_info", info, m.log_time_ns + 1)
    return path


def _ros1_messages(path: Path, topics):
    from rosbags.highlevel import AnyReader

    out = {t: [] for t in topics}
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic in out]
        for conn, _, raw in reader.messages(connections=conns):
            out[conn.topic].append(reader.deserialize(raw, conn.msgtype))
    return out


def _mono(msg) -> np.ndarray:
    assert msg.encoding == "mono8", msg.encoding
    return np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)[:, : msg.width]


def _cloud_xyz(msg) -> np.ndarray:
    """(H * W, 3) float64 x, y, z of a PointCloud2 (ROS 1 or 2 field names)."""
    fields = {f.name: f.offset for f in msg.fields}
    rec = np.frombuffer(msg.data, np.uint8).reshape(-1, msg.point_step)
    return np.stack([rec[:, fields[k]:fields[k] + 4].copy().view(np.float32)[:, 0] for k in "xyz"], axis=1)


def test_stereo_image_proc_and_image_proc_run_on_our_recording(tmp_path):
    _require_image_pipeline()
    rig = load_rig(bundled_rig("croton"))
    out = tmp_path / "out.mcap"
    run_bag(bundled_bag("croton"), rig, rate=0, record=out,
            options=GraphOptions(segment=False, organized=True, parameter_services=False),
            extra_outputs={"left/image_rect_color": Image, "left/image_rect": Image, "right/image_rect": Image})
    raw = _raw_bag(tmp_path / "raw.mcap", bundled_bag("croton"), rig)
    bags = []
    for src in (out, raw):
        dst = src.with_suffix(".bag")
        r = subprocess.run([sys.executable, "-m", "rosbags.convert", "--src", str(src), "--dst",
                            str(dst), "--dst-typestore", "ros1_noetic"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        bags.append(dst)

    ros = Ros1(tmp_path / "ros1")
    try:
        cloud = ros.start("point_cloud2", [str(NODELET), "standalone", "stereo_image_proc/point_cloud2",
                                           "__name:=sip_cloud", "left/camera_info:=left/image_rect/camera_info",
                                           "right/camera_info:=right/image_rect/camera_info",
                                           "points2:=points2_sip"], namespace="/stereo")
        procs = [cloud]
        for side in ("left", "right"):
            procs.append(ros.start(f"image_proc_{side}", [str(IMAGE_PROC), f"__name:=image_proc_{side}",
                                                          "image_rect:=image_rect_ip",
                                                          "image_rect_color:=image_rect_color_ip"],
                                   namespace=f"/stereo/{side}"))
        # and stereo_image_proc's whole pipeline from the raw images and camera_node's raw infos
        # (in /sip: its stereo_image_proc node uses both raw infos in one StereoCameraModel)
        subprocess.run(["rosparam", "set", "/sip/stereo_image_proc/approximate_sync", "true"], env=ros.env,
                       stdin=subprocess.DEVNULL, check=True, capture_output=True)
        procs.append(ros.start("stereo_image_proc", [str(STEREO_IMAGE_PROC)], namespace="/sip"))
        result = tmp_path / "image_pipeline.bag"
        record = ros.start("record", ["rosbag", "record", "-O", str(result), "/stereo/points2_sip",
                                      "/stereo/left/image_rect_ip", "/stereo/right/image_rect_ip",
                                      "/sip/disparity", "/sip/points2"])
        time.sleep(4.0)  # nodelets subscribed, recorder up
        # one bag after the other: the recording's log times are wall-clock, the raw bag's the
        # capture times
        raw_topics = ["/stereo/left/image_raw", "/stereo/left/camera_info", "/stereo/right/image_raw",
                      "/stereo/right/camera_info"]
        for bag, topics in ((bags[0], ["/stereo/disparity", "/stereo/left/image_rect_color",
                                       "/stereo/left/image_rect/camera_info", "/stereo/right/image_rect/camera_info"]),
                            (bags[1], raw_topics),
                            (bags[1], [*raw_topics, *(f"{t}:=/sip{t[len('/stereo'):]}" for t in raw_topics)])):
            rc = ros.run("play", ["rosbag", "play", "-q", "--wait-for-subscribers", "-r", "0.5", str(bag),
                                  "--topics", *topics], timeout_s=120)
            assert rc == 0, ros.log("play")[-2000:]
        time.sleep(5.0)  # the last messages through the nodelets into the recorder
        for p in procs:  # no abort (image_geometry's frame assertion) and still running
            assert p.poll() is None, f"{p.name} exited with {p.returncode}:\n{ros.log(p.name)[-2000:]}"
        ros.stop(record)
    finally:
        ros.close()

    theirs = _ros1_messages(result, ["/stereo/points2_sip", "/stereo/left/image_rect_ip",
                                     "/stereo/right/image_rect_ip", "/sip/disparity"])
    ours = _ros1_messages(bags[0], ["/stereo/points2", "/stereo/left/image_rect", "/stereo/right/image_rect",
                                    "/tf_static", "/stereo/disparity"])
    # clouds: stereo_image_proc's in the left rectified optical frame, ours in canopy_world:
    # put theirs in our frame through the recording's own /tf_static
    tf = {t.child_frame_id: t for m in ours["/tf_static"] for t in m.transforms}
    assert theirs["/stereo/points2_sip"], ros.log("point_cloud2")[-2000:]
    from canopy_stereo.geometry.frames import quaternion_to_rotation

    n_compared = 0
    ours_by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in ours["/stereo/points2"]}
    worst = 0.0
    for msg in theirs["/stereo/points2_sip"]:
        frame = msg.header.frame_id
        t = tf[frame]
        assert t.header.frame_id == ours["/stereo/points2"][0].header.frame_id
        R = quaternion_to_rotation([t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                                    t.transform.rotation.w])
        c = np.array([t.transform.translation.x, t.transform.translation.y, t.transform.translation.z])
        mine = _cloud_xyz(ours_by_stamp[(msg.header.stamp.sec, msg.header.stamp.nanosec)]).astype(np.float64)
        mine_optical = (mine - c) @ R   # world -> left rectified optical frame
        sip = _cloud_xyz(msg).astype(np.float64)
        both = np.all(np.isfinite(sip), axis=1) & np.all(np.isfinite(mine_optical), axis=1)
        assert both.sum() > 0.5 * np.all(np.isfinite(mine_optical), axis=1).sum()
        rel = np.linalg.norm(sip[both] - mine_optical[both], axis=1) / np.linalg.norm(sip[both], axis=1)
        worst = max(worst, float(rel.max()))
        n_compared += 1
    assert n_compared >= 3
    assert worst <= 1e-6, worst
    diffs = []
    # image_proc's rectification of the raw images against ours (rectify_node stamps a pair
    # with the left frame's stamp; the right camera captured 4 ms later: nearest stamp)
    for side in ("left", "right"):
        got = theirs[f"/stereo/{side}/image_rect_ip"]
        mine = ours[f"/stereo/{side}/image_rect"]
        assert len(got) >= 3 and len(mine) >= 3
        for a_msg in got:
            b_msg = min(mine, key=lambda m: abs(_stamp(m) - _stamp(a_msg)))
            assert abs(_stamp(b_msg) - _stamp(a_msg)) < 20_000_000
            a, b = _mono(a_msg).astype(int), _mono(b_msg).astype(int)
            inside = (a > 0) & (b > 0)   # both images have content (borders are black in both)
            assert inside.mean() > 0.8
            diffs.append(float(np.median(np.abs(a - b)[inside])))
    assert max(diffs) <= 1, diffs
    # stereo_image_proc's own matching on its own rectification from our raw infos: the same
    # rectified geometry as ours, so its disparities agree with ELAS's where both have one
    assert len(theirs["/sip/disparity"]) >= 2  # approximate sync of 4 frames: the first may wait
    disparity_diffs = []
    for msg in theirs["/sip/disparity"]:
        mine = min(ours["/stereo/disparity"], key=lambda m: abs(_stamp(m) - _stamp(msg)))
        assert abs(_stamp(mine) - _stamp(msg)) < 20_000_000
        a, b = _disparity(msg), _disparity(mine)
        both = np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
        assert both.mean() > 0.3
        disparity_diffs.append(float(np.median(np.abs(a - b)[both])))
    assert max(disparity_diffs) < 0.5, disparity_diffs
    print(f"stereo_image_proc point_cloud2 vs our points2: worst relative difference {worst:.2e} over "
          f"{n_compared} clouds; image_proc image_rect vs ours: median grey-level differences {diffs}; "
          f"stereo_image_proc (whole pipeline, raw infos) vs our disparity: median |difference| {disparity_diffs} px")


def _disparity(msg) -> np.ndarray:
    """A DisparityImage's 32FC1 image (H, W), NaN where invalid (below min_disparity)."""
    img = msg.image
    d = np.frombuffer(img.data, np.float32).reshape(img.height, img.step // 4)[:, : img.width].astype(np.float64)
    d[~(d >= msg.min_disparity)] = np.nan
    return d


def _stamp(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
