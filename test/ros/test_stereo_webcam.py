"""One-device stereo webcams: camera_node splits a side-by-side MJPEG capture (a video file
written with cv2.VideoWriter 'MJPG', as such a webcam records) into left and right, raw and
compressed, with one stamp per capture; the graph turns it into clouds."""
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2  # noqa: E402

from canopy_stereo.io.image_codec import decode_compressed  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.camera_info import default_camera_frame  # noqa: E402
from canopy_stereo.ros.context import private_domain_id, wait_for  # noqa: E402
from test.conftest import REPO  # noqa: E402
from test.support.nodes import TIMEOUT, node_kwargs  # noqa: E402
from test.support.ros_harness import Probe, ProcessGroup, croton_frames  # noqa: E402
from test.support.ros_harness import wait_for as wait_alive  # noqa: E402

pytestmark = pytest.mark.ros

RIG = REPO / "config" / "croton_rig.yaml"


def _psnr(a, b) -> float:
    mse = float(np.mean((a.astype(float) - b.astype(float)) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


@pytest.fixture(scope="module")
def side_by_side_video(tmp_path_factory):
    """An MJPEG AVI of the croton's pairs side by side (1280x480), and the pairs."""
    frames = croton_frames()
    path = tmp_path_factory.mktemp("sbs") / "stereo_webcam.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (1280, 480))
    assert writer.isOpened()
    for left, right in frames * 2:
        writer.write(np.concatenate([left, right], axis=1))
    writer.release()
    return path, frames


def _stamp(msg) -> int:
    return convert.stamp_to_ns(msg.header.stamp)


def test_side_by_side_mjpeg_is_split_with_one_stamp_for_both_sides(harness, side_by_side_video):
    from canopy_stereo.ros.nodes.camera import CameraNode

    path, frames = side_by_side_video
    node = harness.add(CameraNode(**node_kwargs(harness, rig=load_rig(RIG), device=str(path), layout="side_by_side",
                                                 transport="both", fps=20.0, jpeg_quality=95,
                                                 diagnostic_period=0.0)))
    out = {t: harness.collect(cls, t) for t, cls in [
        ("left/image_raw", Image), ("right/image_raw", Image),
        ("left/image_raw/compressed", CompressedImage), ("right/image_raw/compressed", CompressedImage),
        ("left/camera_info", CameraInfo), ("right/camera_info", CameraInfo)]}
    assert wait_for(lambda: all(len(v) >= 6 for v in out.values()), TIMEOUT), {t: len(v) for t, v in out.items()}
    # a file has no capture clock: stamped at reception, the spread of the intervals reported
    values = {kv.key: kv.value for kv in node.diagnostics.status().values}
    assert float(values["stamp jitter ms mean"]) >= 0 and "stamp latency ms mean" not in values
    harness.remove(node)
    node.destroy_node()
    stamps = {t: [_stamp(m) for m in v[:6]] for t, v in out.items()}
    assert len(set(stamps["left/image_raw"])) == 6  # one stamp per capture ...
    for t in out:  # ... the same on both sides, raw, compressed and camera_info
        assert stamps[t] == stamps["left/image_raw"], t
    left, right = (convert.msg_to_image(out[f"{s}/image_raw"][0]) for s in ("left", "right"))
    assert left.shape == right.shape == (480, 640, 3)
    assert _psnr(left, frames[0][0]) > 30 and _psnr(right, frames[0][1]) > 30  # the right halves, in order
    assert _psnr(left, frames[0][1]) < _psnr(left, frames[0][0]) - 3
    jpeg = out["right/image_raw/compressed"][0]
    assert jpeg.format == "bgr8; jpeg compressed bgr8" and jpeg.header.frame_id == default_camera_frame("right")
    assert _psnr(decode_compressed(jpeg.data, jpeg.format), frames[0][1]) > 30
    info = out["right/camera_info"][0]
    assert (info.width, info.height) == (640, 480) and info.p[3] < 0  # the rig's right camera (Tx = -f B)


@pytest.mark.slow
def test_a_side_by_side_webcam_drives_the_graph_to_clouds(side_by_side_video, tmp_path):
    """camera_node (side_by_side, compressed) and the graph, one process each: clouds come out,
    and left and right frames carry identical stamps."""
    path, _ = side_by_side_video
    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    probe = None
    try:
        group.start_graph(RIG, nodes=("disparity_node", "point_cloud_node"))
        group.start("rectify_node", params_files=[RIG], params={"image_transport": "compressed", "fps": 5.0})
        group.start("camera_node", params_files=[RIG], params={
            "device": str(path), "layout": "side_by_side", "transport": "compressed", "fps": 5.0})
        probe = Probe(group.domain_id)
        left = probe.subscribe(CompressedImage, "left/image_raw/compressed")
        right = probe.subscribe(CompressedImage, "right/image_raw/compressed")
        points = probe.subscribe(PointCloud2, "points2")
        assert wait_alive(lambda: len(points) >= 3 and len(left) >= 3 and len(right) >= 3, 180.0,
                          group=group), group.logs()
        time.sleep(0.5)
        lefts, rights = set(left.stamps()), set(right.stamps())
        assert len(lefts) >= 3 and len(lefts & rights) >= len(lefts) - 1  # the newest may be in flight
        # every cloud is stamped with a capture's one stamp (clouds of captures the probe saw)
        seen = {s for s in points.stamps() if s is not None and s >= min(lefts)}
        assert seen and seen <= lefts
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()


@pytest.mark.slow
def test_canopy_graph_from_one_stereo_webcam_records_clouds_and_one_stamp_per_pair(side_by_side_video, tmp_path):
    """``canopy_graph --stereo-camera sbs.avi --layout side_by_side --record OUT --compress-images``:
    one camera_node feeds the graph in one process; the recording has clouds, and the left and
    right JPEG frames carry the same stamps."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.recorder import header_stamp_from_cdr

    path, _ = side_by_side_video
    out, fps = tmp_path / "rec.mcap", 4.0
    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    graph = group.start("canopy_graph", "--rig", RIG, "--stereo-camera", path, "--layout", "side_by_side",
                        "--fps", fps, "--matcher", "sgbm", "--no-segment", "--record", out, "--compress-images")
    try:
        deadline, recording_at = time.monotonic() + 120, None
        while time.monotonic() < deadline and graph.alive():
            if (recording_at is None and "recording /stereo/points2" in graph.log() and out.is_file()
                    and out.stat().st_size > 2_000_000):
                recording_at = time.monotonic()
            if recording_at is not None and time.monotonic() - recording_at > 4.0 / fps:  # a few more frames
                break
            time.sleep(0.25)
    finally:
        code = graph.stop(timeout_s=60)
    assert code == 0, graph.log()[-3000:]
    bag = BagReader(out)
    stamps = {t: {header_stamp_from_cdr(m.data) for m in bag.messages([t])} for t in
              ("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed", "/stereo/points2")}
    assert stamps["/stereo/points2"], graph.log()[-3000:]
    left, right = stamps["/stereo/left/image_raw/compressed"], stamps["/stereo/right/image_raw/compressed"]
    assert len(left) >= 2 and len(left ^ right) <= 1  # the same stamps (the last may be cut by the stop)
    assert stamps["/stereo/points2"] <= left


class _MjpegDevice:
    """A V4L2 device delivering MJPEG with RGB conversion off: ``read`` hands over the JPEG
    bytes as a (1, N) row, as OpenCV does, and the buffer timestamp on CLOCK_MONOTONIC."""

    def __init__(self, jpegs):
        self.jpegs, self.k = jpegs, 0
        self.captured_ns = 0

    def read(self):
        time.sleep(0.02)
        self.captured_ns = time.monotonic_ns() - 15_000_000  # exposure started 15 ms ago
        data = self.jpegs[self.k % len(self.jpegs)]
        self.k += 1
        return True, np.frombuffer(data, np.uint8).reshape(1, -1)

    def get(self, prop):
        return self.captured_ns / 1e6 if prop == cv2.CAP_PROP_POS_MSEC else 0.0

    def release(self):
        pass


def test_a_devices_mjpeg_is_published_as_it_came_with_its_capture_stamps(harness, monkeypatch):
    """transport compressed from an MJPEG device: the device's own bytes on image_raw/compressed
    (no decode, no re-encode), stamped with the driver's capture time (15 ms before reception)."""
    from canopy_stereo.io.image_codec import encode_compressed
    from canopy_stereo.ros.nodes import camera

    jpegs = [encode_compressed(np.full((48, 64, 3), v, np.uint8), quality=70)[1] for v in (40, 120)]
    opened = []

    def fake_open(source, **settings):
        opened.append(settings)
        return _MjpegDevice(jpegs)

    monkeypatch.setattr(camera, "open_capture", fake_open)
    node = harness.add(camera.CameraNode(**node_kwargs(harness, device="/dev/video7", camera_name="left",
                                                       fourcc="MJPG", transport="compressed", fps=30.0,
                                                       diagnostic_period=0.0)))
    out = harness.collect(CompressedImage, "left/image_raw/compressed")
    raw = harness.collect(Image, "left/image_raw")
    assert wait_for(lambda: len(out) >= 4, TIMEOUT)
    harness.remove(node)
    node.destroy_node()
    assert opened[0]["device_jpeg"] is True  # asked OpenCV for the undecoded stream
    assert {bytes(m.data) for m in out[:4]} == set(jpegs) and not raw  # the device's bytes, nothing else
    values = {kv.key: kv.value for kv in node.diagnostics.status().values}
    assert 14.0 <= float(values["stamp latency ms mean"]) < 200.0  # capture -> reception, measured
