"""``canopy-stereo view``: recordings written with --save, read back with Rerun's own reader."""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from test.conftest import REPO, run_cli_subprocess

CROTON_BAG = REPO / "bags" / "croton.mcap"
CROTON_RIG = REPO / "config" / "croton_rig.yaml"


@pytest.mark.slow
def test_view_without_rerun_says_what_to_install(tmp_path):
    code = ("import sys; sys.modules['rerun'] = None\n"
            "from canopy_stereo.cli import main\n"
            f"sys.exit(main(['view', {str(CROTON_BAG)!r}, '--save', {str(tmp_path / 'x.rrd')!r}]))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'canopy_stereo[viz]'" in lines[0], res.stderr
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.slow
def test_view_bad_options_one_line_exit_2(tmp_path):
    pytest.importorskip("rerun")
    for args in ([tmp_path / "missing.mcap"],
                 [CROTON_BAG, "--port", "9000"],
                 [CROTON_BAG, "--save", tmp_path / "x.rrd", "--web"],
                 [CROTON_BAG, "--save", tmp_path / "x.txt"]):
        res = run_cli_subprocess("view", *args, timeout=120)
        assert res.returncode == 2, (args, res.stderr)
        assert len(res.stderr.strip().splitlines()) == 1 and "error:" in res.stderr, res.stderr


def _bag_without_rig(tmp_path):
    """The bundled croton bag's messages without its metadata records (a bag with no rig)."""
    from canopy_stereo.bag import BagReader, BagWriter
    from canopy_stereo.bag.metadata import rig_from_bag

    bare = tmp_path / "bare.mcap"
    with BagWriter(bare) as w:
        for m in BagReader(CROTON_BAG).messages(log_time_order=True):
            w.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    assert rig_from_bag(CROTON_BAG) is not None and rig_from_bag(bare) is None
    return bare


def _rrd_entities(path):
    """entity path -> list of (stamp_ns or None, {column: value}) rows, from Rerun's own reader."""
    from rerun.chunk import RrdReader

    rows: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        names = rb.schema.names
        stamps = rb.column(names.index("stamp")).cast("int64").to_pylist() if "stamp" in names else None
        for i in range(rb.num_rows):
            row = {n: rb.column(j)[i] for j, n in enumerate(names)}
            rows.setdefault(chunk.entity_path, []).append((None if stamps is None else stamps[i], row))
    return rows


def _values(cell) -> np.ndarray:
    """A list<fixed_size_list<float>> cell as a numpy (N, k) array."""
    items = cell.values
    width = items.type.list_size
    return np.asarray(items.values.to_numpy(zero_copy_only=False)).reshape(-1, width)


@pytest.fixture(scope="module")
def croton_recording(tmp_path_factory):
    """``canopy-stereo view bags/croton.mcap --rig ... --save croton.rrd`` (raw frames through the graph)."""
    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    out = tmp_path_factory.mktemp("view") / "croton.rrd"
    res = run_cli_subprocess("view", CROTON_BAG, "--rig", CROTON_RIG, "--save", out, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert out.is_file() and "wrote" in res.stdout
    return out


@pytest.mark.slow
@pytest.mark.ros
def test_view_save_croton_one_cloud_per_frame_image_depth_pinhole(croton_recording):
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.convert import stamp_to_ns

    left_stamps = sorted(stamp_to_ns(msg.header.stamp)
                         for _, msg in BagReader(CROTON_BAG).read("/stereo/left/image_raw"))
    ents = _rrd_entities(croton_recording)
    clouds = ents["/world/cloud"]
    assert sorted(s for s, _ in clouds) == left_stamps  # one cloud per frame, on the stamp timeline
    for entity in ("/world/camera/image", "/world/camera/depth", "/world/camera/mask"):
        assert sorted(s for s, _ in ents[entity]) == left_stamps, entity
    camera = [row for _, row in ents["/world/camera"]]
    pinhole = [r for r in camera if "Pinhole:image_from_camera" in r and r["Pinhole:image_from_camera"].is_valid]
    pose = [r for r in camera if "Transform3D:translation" in r and r["Transform3D:translation"].is_valid]
    assert pinhole and pose
    # the image and the cloud line up: projecting each cloud through the logged pinhole
    # and pose lands on the logged depth (metres) of the same frame
    K = _values(pinhole[0]["Pinhole:image_from_camera"]).reshape(3, 3).T  # stored column-major
    C = _values(pose[0]["Transform3D:translation"])[0]
    R_wc = _values(pose[0]["Transform3D:mat3x3"]).reshape(3, 3).T
    w, h = (int(v) for v in _values(pinhole[0]["Pinhole:resolution"])[0])
    depths = {s: row for s, row in ents["/world/camera/depth"]}
    for stamp, row in clouds:
        pts = _values(row["Points3D:positions"])
        assert len(pts) > 50_000  # a dense cloud, metres
        cam = (pts - C) @ R_wc  # camera coordinates (R_wc world from camera)
        uvw = cam @ K.T
        uv = np.rint(uvw[:, :2] / uvw[:, 2:]).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        assert inside.mean() > 0.99
        blob = depths[stamp]["DepthImage:buffer"].values[0].values  # one uint8 blob per image
        buf = np.frombuffer(np.asarray(blob.to_numpy(zero_copy_only=False), np.uint8).tobytes(),
                            np.float32).reshape(h, w)
        z = buf[uv[inside, 1], uv[inside, 0]]
        ok = z > 0
        rel = np.abs(z[ok] - cam[inside, 2][ok]) / z[ok]
        assert ok.mean() > 0.95 and np.median(rel) < 0.005, (ok.mean(), np.median(rel))
    # measured leaves and canopy per frame, labelled in millimetres
    assert sorted(s for s, _ in ents["/world/canopy"]) == left_stamps
    label = ents["/world/canopy"][0][1]["Boxes3D:labels"].as_py()[0]
    assert label.startswith("canopy h ") and label.endswith(" mm")
    height_mm = ents["/measurements/height_mm"][0][1]["Scalars:scalars"].as_py()[0]
    assert 300 < height_mm < 700  # the croton stands about half a metre tall
    assert any(lbl for _, row in ents["/world/camera/leaves"] for lbl in row["LineStrips2D:labels"].as_py())
    # the layout is saved with the recording
    from rerun.chunk import RrdReader

    assert RrdReader(croton_recording).blueprints()


@pytest.mark.slow
@pytest.mark.ros
def test_view_reopens_saved_recording(croton_recording, tmp_path):
    copy = tmp_path / "again.rrd"
    res = run_cli_subprocess("view", croton_recording, "--save", copy, timeout=120)
    assert res.returncode == 0, res.stderr
    assert len(_rrd_entities(copy)["/world/cloud"]) == 4


@pytest.mark.slow
@pytest.mark.ros
def test_view_raw_bag_without_rig_asks_for_rig(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    bare = _bag_without_rig(tmp_path)  # (the bundled bag carries its rig: a copy without it)
    res = run_cli_subprocess("view", bare, "--save", tmp_path / "x.rrd", timeout=120)
    assert res.returncode == 2
    assert "--rig" in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert not (tmp_path / "x.rrd").exists()


@pytest.mark.slow
@pytest.mark.ros
def test_view_recorded_outputs_bag_as_recorded(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    outputs = tmp_path / "outputs.mcap"
    res = run_cli_subprocess("run", "--bag", CROTON_BAG, "--rig", CROTON_RIG, "--rate", "0",
                             "--organized", "--record", outputs, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    rrd = tmp_path / "outputs.rrd"
    res = run_cli_subprocess("view", outputs, "--save", rrd, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "recorded frames shown" in res.stdout
    ents = _rrd_entities(rrd)
    assert len(ents["/world/cloud"]) == 4
    assert len(ents["/world/camera/depth"]) == 4 and len(ents["/world/camera/mask"]) == 4
    assert "/world/camera/image" not in ents  # not recorded by `run --record`: not invented
    # organized clouds and masks were recorded: leaves and canopy are measured per frame
    assert len(ents["/world/canopy"]) == 4 and len(ents["/measurements/height_mm"]) == 4


@pytest.mark.slow
@pytest.mark.ros
def test_view_takes_the_rig_from_the_bag_metadata(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    from canopy_stereo.bag import BagReader
    from canopy_stereo.bag.metadata import rig_from_bag
    from canopy_stereo.io.rig import load_rig
    from test.support.ros_harness import record_with_bag_record

    # recorded the way a user does: bag_record --rig (its own process) of the raw frames
    bag, bare = tmp_path / "with_rig.mcap", _bag_without_rig(tmp_path)
    frames = [(m.topic, m.type_name, m.data) for m in BagReader(bare).messages(log_time_order=True)
              if m.topic.endswith("image_raw")]
    record_with_bag_record(bag, frames, args=["--rig", CROTON_RIG])
    assert rig_from_bag(bare) is None
    rig = rig_from_bag(bag)
    assert np.allclose(rig.P_left, load_rig(CROTON_RIG).P_left)
    rrd = tmp_path / "x.rrd"
    res = run_cli_subprocess("view", bag, "--save", rrd, "--no-measure", timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    ents = _rrd_entities(rrd)
    assert len(ents["/world/cloud"]) == 4
    assert any(r["Transform3D:translation"].is_valid for _, r in ents["/world/camera"]
               if "Transform3D:translation" in r)  # the camera is placed in the world
    # `run` without --rig takes it from the same record (one reader: canopy_stereo.bag.metadata)
    res = run_cli_subprocess("run", "--bag", bag, "--rate", "0", "--matcher", "sgbm", "--no-segment", timeout=600)
    assert res.returncode == 0 and "frames out: 4" in res.stdout, res.stderr[-2000:]
    res = run_cli_subprocess("run", "--bag", bare, "--rate", "0", timeout=120)
    assert res.returncode == 2 and "--rig" in res.stderr and len(res.stderr.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.ros
def test_run_view_streams_live_and_serves_until_ctrl_c(tmp_path):
    """Headless (no DISPLAY): ``run --view`` serves the web viewer on localhost, streams every
    frame to it while the graph runs, and keeps serving until Ctrl-C."""
    import os
    import signal
    import threading

    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["PYTHONUNBUFFERED"] = "1"
    proc = subprocess.Popen([sys.executable, "-m", "canopy_stereo.cli", "run", "--bag", str(CROTON_BAG),
                             "--rig", str(CROTON_RIG), "--rate", "0", "--view"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, cwd=REPO, env=env)
    out = []
    reader = threading.Thread(target=lambda: out.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and not any("Ctrl-C to stop" in line for line in list(out)):
            if proc.poll() is not None:
                break
            time.sleep(0.5)
        text = "".join(out)
        assert "viewer: http://127.0.0.1:" in text and "frames out: 4" in text, text
        shown = int(text.split("viewer: showed ")[1].split()[0])
        assert 1 <= shown <= 4, text  # frames the viewer could not keep up with are skipped, not queued
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
    assert proc.returncode == 0


def test_rerun_pin_is_one_version_everywhere():
    """setup.py's extras, the install hint and the installed rerun-sdk agree."""
    import re

    from canopy_stereo.viz import INSTALL_HINT, RERUN_REQUIREMENT

    pins = set(re.findall(r"rerun-sdk==([\d.]+)", (REPO / "setup.py").read_text()))
    assert pins == {RERUN_REQUIREMENT.split("==")[1]} and RERUN_REQUIREMENT in INSTALL_HINT
    rr = pytest.importorskip("rerun")
    assert rr.__version__ == RERUN_REQUIREMENT.split("==")[1]
