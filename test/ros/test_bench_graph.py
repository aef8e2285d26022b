"""benchmarks/bench_graph.py: its configurations, frames, rigs and CPU accounting (the speed
figures themselves are the benchmark's, not a test's)."""
from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
pytest.importorskip("rclpy")
import bench_graph  # noqa: E402


def test_configs_parse_and_cover_the_matrix():
    c = bench_graph.Config.parse("processes:elas:mask:640x480")
    assert (c.mode, c.matcher, c.mask, c.size) == ("processes", "elas", True, "640x480")
    assert str(c) == "processes:elas:mask:640x480"
    assert c.nodes == ("rectify_node", "disparity_node", "segment_node", "point_cloud_node")
    assert "segment_node" not in bench_graph.Config.parse("inprocess:sgbm:nomask:320x240").nodes
    c = bench_graph.Config.parse("inprocess:elas:mask:640x480:compressed")
    assert c.transport == "compressed" and str(c) == "inprocess:elas:mask:640x480:compressed"
    assert bench_graph.Config.parse("inprocess:elas:mask:640x480:raw") == bench_graph.Config.parse(
        "inprocess:elas:mask:640x480")
    every = bench_graph.all_configs()
    assert len(every) == len(set(every)) == 32
    assert set(bench_graph.HD_CONFIGS) == {"processes:elas:mask:1280x720", "processes:elas:nomask:1280x720",
                                           "processes:elas:mask:1280x720:compressed",
                                           "processes:elas:nomask:1280x720:compressed"}
    for bad, word in (("processes:elas:mask", "MODE:MATCHER:MASK:SIZE"), ("threads:elas:mask:640x480", "mode"),
                      ("processes:bm:mask:640x480", "matcher"), ("processes:elas:on:640x480", "mask"),
                      ("processes:elas:mask:800x600", "size"), ("processes:elas:mask:640x480:png", "transport")):
        with pytest.raises(ValueError, match=word):
            bench_graph.Config.parse(bad)


def test_node_parameters_from_the_command_line():
    assert bench_graph.parse_node_parameter("disparity_node:elas.subsampling=true") == (
        "disparity_node", "elas.subsampling", True)
    assert bench_graph.parse_node_parameter("segment_node:recut_every=1") == ("segment_node", "recut_every", 1)
    for bad in ("disparity_node", "disparity_node:threads", ":x=1"):
        with pytest.raises(ValueError, match="NODE:NAME=VALUE"):
            bench_graph.parse_node_parameter(bad)


@pytest.mark.parametrize("size", ["320x240", "640x480", "1280x720", "1280x960"])
def test_bench_frames_and_scaled_rig_agree(size):
    """The scaled, cropped rig projects a world point where the crop + resize puts its pixel."""
    from canopy_stereo.geometry.camera import project
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_rig

    rig, frames = bench_graph.bench_frames("plants", size, n_frames=3)
    w, h = (int(v) for v in size.split("x"))
    assert rig.image_size == (w, h)
    assert len(frames) == 3 and all(f.shape == (h, w, 3) and f.dtype == np.uint8 for p in frames for f in p)
    assert not np.array_equal(frames[0][0], frames[1][0])  # drift and noise change every frame
    base = load_rig(bundled_rig("plants"))
    s = bench_graph.SIZES[size]
    x0, y0 = bench_graph.PLANTS_CROP
    y0 += (480 - round(h / s)) // 2  # 1280x720: the middle 640x360 rows of the 640x480 window
    X = np.array([[30.0, -20.0, 900.0], [-50.0, 40.0, 1200.0]])  # millimetres, in front of the rig
    for P_base, P in ((base.P_left, rig.P_left), (base.P_right, rig.P_right)):
        uv = project(P_base, X) - [x0, y0]
        np.testing.assert_allclose(project(P, X), s * uv + (s - 1) / 2, atol=1e-9)
    assert rig.extra["disp_min"] <= base.extra["disp_min"] * s <= base.extra["disp_max"] * s <= rig.extra["disp_max"]


@pytest.mark.slow
def test_webcam_lens_frames_rectify_back_to_the_pair():
    """``--lens webcam`` (the default): the drifting real pair as two turned webcams with barrel
    distortion record it. rectify_node's rectification of that rig resamples (no identity maps)
    and brings the frames back to a rectified pair: matched features on one row (as in the
    pre-rectified pair), at disparities inside the rig's search range, moved by the principal
    points' difference the rig's range moved by."""
    import cv2

    from canopy_stereo.geometry.rectification import StereoRectifier
    from canopy_stereo.geometry.rig_rectification import rectification_for_rig

    rig0, frames0 = bench_graph.bench_frames("plants", "640x480", n_frames=1, lens="none")
    rig, frames = bench_graph.bench_frames("plants", "640x480", n_frames=1, lens="webcam")
    assert rig.D_left[0] < 0 and not np.allclose(rig.P_left[:, :3], rig0.P_left[:, :3])
    rectifier = StereoRectifier(rig, rectification_for_rig(rig))
    w, h = rig.image_size
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), axis=-1)
    assert np.abs(rectifier.coordinates("left") - grid).max() > 10  # really resampled
    orb = cv2.ORB_create(3000)

    def matches(left, right):
        kl, dl = orb.detectAndCompute(cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), None)
        kr, dr = orb.detectAndCompute(cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), None)
        pairs = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
        d = np.array([np.subtract(kl[m.queryIdx].pt, kr[m.trainIdx].pt) for m in pairs])
        return d[np.abs(d[:, 1]) < 3]  # (dx, dy) of the matches on nearly one row

    raw = matches(*frames[0])
    assert np.median(np.abs(raw[:, 1])) > 1.0 or len(raw) < 200  # the raw pair is not rectified
    before, after = matches(*frames0[0]), matches(*rectifier.rectify(*frames[0]))
    assert len(after) > 300 and np.median(np.abs(after[:, 1])) < 1.0
    shift = rig.extra["disp_min"] - rig0.extra["disp_min"]
    assert np.median(after[:, 0]) == pytest.approx(np.median(before[:, 0]) + shift, abs=3.0)
    assert rig.extra["disp_min"] <= np.percentile(after[:, 0], 10) <= np.percentile(after[:, 0], 90) \
        <= rig.extra["disp_max"]


def test_cpu_accounting_sees_a_busy_thread():
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            sum(range(1000))

    t = threading.Thread(target=spin, name="canopy_graph:rectify_node")
    before_proc = bench_graph.proc_cpu_seconds()
    before = bench_graph.in_process_cpu_seconds().get("rectify_node", 0.0)
    t.start()
    time.sleep(0.5)
    during = bench_graph.in_process_cpu_seconds().get("rectify_node", 0.0)
    stop.set()
    t.join()
    assert during - before >= 0.1  # most of 0.5 s (a busy machine shares the core)
    assert bench_graph.proc_cpu_seconds() - before_proc >= during - before - 0.02
    assert bench_graph.proc_peak_rss_mb() > 10
    assert [bench_graph.thread_owner(n) for n in ("canopy_graph:segment_node", "disparity_node:latest",
                                                  "elas_0", "bench:probe", "Thread-3")] == [
        "segment_node", "disparity_node", "disparity_node", "feed", "dds"]


@pytest.mark.slow
def test_one_configuration_reports_every_figure(tmp_path):
    """A short in-process run at 320x240: clouds arrive, and every node has CPU and outputs."""
    r = bench_graph.run_config(bench_graph.Config.parse("inprocess:sgbm:mask:320x240"), n_frames=10,
                               rate_hz=10.0, log_dir=tmp_path,
                               node_parameters={"segment_node": {"recut_every": 3}})
    assert 8 < r["offered_per_s"] < 12
    assert r["delivered_fraction"] > 0 and r["latency_median_ms"] > 0
    assert r["latency_p95_ms"] >= r["latency_median_ms"]
    for node in ("rectify_node", "disparity_node", "segment_node", "point_cloud_node"):
        assert r["nodes"][node]["cpu_ms_per_pair"] > 0, node
        assert r["nodes"][node]["out"] > 0, node
    assert r["process_rss_peak_mb"] > 50
    lines = bench_graph.format_result(r)
    assert lines[0].startswith("inprocess:sgbm:mask:320x240") and "segment" in lines[1]


@pytest.mark.shared
def test_aloe_scene_holds_disparities_to_about_130_px_within_its_rig_range(shared_data):
    """``--scene aloe`` (issue 28's second 640x480 scene): the ground truth, scaled and cropped as
    the frames are, reaches about 130 px and lies inside the rig's search range."""
    import cv2

    from test.support.aloe import ALOE_CROP, ALOE_SCALE, aloe_dir

    rig, frames = bench_graph.bench_frames("aloe", "640x480", n_frames=2)
    assert rig.image_size == (640, 480) and frames[0][0].shape == (480, 640, 3)
    gt = cv2.imread(str(aloe_dir(shared_data) / "aloeGT.png"), cv2.IMREAD_GRAYSCALE).astype(np.float32)
    gt = cv2.resize(gt, None, fx=ALOE_SCALE, fy=ALOE_SCALE, interpolation=cv2.INTER_NEAREST) * ALOE_SCALE
    x0, y0 = ALOE_CROP
    window = gt[y0:y0 + 480, x0:x0 + 640]
    known = window[window > 0]
    assert 120 <= known.max() <= rig.extra["disp_max"] and known.min() >= rig.extra["disp_min"]
    assert -rig.P_right[0, 3] / rig.P_right[0, 0] == pytest.approx(160.0)  # Middlebury 2006's baseline, mm
