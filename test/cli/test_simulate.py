"""``canopy-stereo simulate``: files written, their contents, and error handling; ``simulate calibration``."""
import json

import cv2
import numpy as np
import pytest

from canopy_stereo.cli import main
from canopy_stereo.geometry.board_corners import detect_board_corners
from canopy_stereo.geometry.board_placements import board_world_points, paper_layout_placements
from canopy_stereo.geometry.camera import project
from canopy_stereo.io.placements import load_placements, write_placements
from canopy_stereo.io.rig import load_rig, save_rig
from canopy_stereo.sim import default_rig_path, rig_at_resolution


@pytest.fixture(scope="module")
def small_rig_file(tmp_path_factory, paper_rig):
    path = tmp_path_factory.mktemp("rig") / "small_rig.yaml"
    save_rig(rig_at_resolution(paper_rig, 0.25), path, comment="paper rig at 160x120")
    return path


def test_simulate_writes_images_ground_truth_and_rig(tmp_path, small_rig_file):
    out = tmp_path / "croton"
    assert main(["simulate", "croton", "-o", str(out), "--rig", str(small_rig_file),
                 "--seed", "2"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"left.png", "right.png", "xyz_left.npy", "xyz_right.npy", "leaf_ids_left.png",
            "leaf_ids_right.png", "truth.json", "rig.yaml"} <= names
    assert (out / "rig.yaml").read_bytes() == small_rig_file.read_bytes()
    rig = load_rig(out / "rig.yaml")
    left = cv2.imread(str(out / "left.png"))
    assert left.shape == (120, 160, 3)
    xyz = np.load(out / "xyz_left.npy")
    assert xyz.shape == (120, 160, 3)
    ok = np.all(np.isfinite(xyz), axis=2)
    vv, uu = np.nonzero(ok)
    assert np.abs(project(rig.P_left, xyz[ok]) - np.column_stack([uu, vv])).max() < 0.05
    ids = cv2.imread(str(out / "leaf_ids_left.png"), cv2.IMREAD_UNCHANGED)
    assert ids.dtype == np.uint16 and ids.shape == (120, 160)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["scene"] == "croton" and truth["seed"] == 2 and truth["world_unit"] == "mm"
    by_id = {lf["id"]: lf for lf in truth["leaves"]}
    assert by_id[1]["length"] == pytest.approx(160.0) and by_id[1]["width"] == pytest.approx(97.0)
    assert {"length", "width", "area", "pose"} <= set(by_id[2])
    for leaf_id, lf in by_id.items():
        assert lf["pixels_left"] == int((ids == leaf_id).sum())


def test_simulate_frames_go_to_numbered_folders(tmp_path, small_rig_file):
    out = tmp_path / "seq"
    assert main(["simulate", "seedling_tray", "-o", str(out), "--rig", str(small_rig_file),
                 "--frames", "3", "--supersample", "1", "--clean"]) == 0
    frames = sorted(p.name for p in out.iterdir() if p.is_dir())
    assert frames == ["frame_0000", "frame_0001", "frame_0002"]
    truths = [json.loads((out / f / "truth.json").read_text()) for f in frames]
    assert [t["frame"] for t in truths] == [0, 1, 2]
    assert truths[0]["leaves"][0]["pose"]["tip"] != truths[2]["leaves"][0]["pose"]["tip"]
    assert truths[0]["camera_effects"]["noise_sigma"] == 0.0
    assert (out / "rig.yaml").is_file()


def test_default_rig_is_the_papers(tmp_path):
    assert default_rig_path().name == "paper_rig.yaml"
    # render the default rig quickly: only check that it is the rig copied out
    out = tmp_path / "default"
    assert main(["simulate", "citrus_branch", "-o", str(out), "--supersample", "1"]) == 0
    assert (out / "rig.yaml").read_bytes() == default_rig_path().read_bytes()
    assert cv2.imread(str(out / "right.png")).shape == (480, 640, 3)


@pytest.mark.parametrize("argv, message", [
    (["simulate", "tomato", "-o", "{out}"], "unknown scene"),
    (["simulate", "croton", "-o", "{out}", "--frames", "0"], "--frames"),
    (["simulate", "croton", "-o", "{out}", "--seed", "-3"], "--seed"),
    (["simulate", "croton", "-o", "{out}", "--rig", "{out}/missing.yaml"], "rig"),
])
def test_simulate_reports_bad_input_in_one_line(tmp_path, capsys, argv, message):
    argv = [a.replace("{out}", str(tmp_path / "o")) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_cli_simulate_calibration_writes_images_and_placements(tmp_path, cli, paper_rig):
    pl = paper_layout_placements(marks_per_line=1)
    write_placements(pl, tmp_path / "mine.yaml")
    code, out, err = cli("simulate", "calibration", "-o", tmp_path / "sim", "--placements",
                         tmp_path / "mine.yaml", "--samples", "4")
    assert code == 0, err
    files = sorted(p.name for p in (tmp_path / "sim").iterdir())
    assert files == ["left_00.png", "left_01.png", "left_02.png", "placements.yaml", "rig.yaml",
                     "right_00.png", "right_01.png", "right_02.png"]
    back = load_placements(tmp_path / "sim" / "placements.yaml")
    assert back.pairs == [0, 1, 2]
    import cv2

    img = cv2.imread(str(tmp_path / "sim" / "left_01.png"))
    assert img.shape == (480, 640, 3)
    # the board is where the written rig and placement put it (either corner order: 7x5 is symmetric)
    from canopy_stereo.io.rig import load_rig

    corners = detect_board_corners(img, (7, 5))
    x = project(load_rig(tmp_path / "sim" / "rig.yaml").P_left, board_world_points(back[1], back.pattern, back.square))
    rms = min(np.sqrt(np.mean(np.sum((c - x) ** 2, 1))) for c in (corners, corners[::-1]))
    assert rms < 0.1, rms
    assert "calibrate with: canopy-stereo calibrate --world-rig" in out


@pytest.mark.slow
@pytest.mark.ros
def test_simulate_field_sequence_writes_a_compressed_bag_stamped_at_capture(tmp_path, small_rig_file):
    """``--motion/--skew/--jpeg-quality --bag --compressed``: frame folders with the capture
    instants in their truth, and a bag of JPEG CompressedImages stamped 8 ms apart + truth depth."""
    pytest.importorskip("rclpy")
    from canopy_stereo.bag import BagReader
    from canopy_stereo.bag.metadata import canopy_metadata
    from canopy_stereo.ros.bundled import read_truth_depths

    out, bag_path = tmp_path / "field", tmp_path / "field.mcap"
    assert main(["simulate", "croton", "-o", str(out), "--rig", str(small_rig_file), "--frames", "2",
                 "--supersample", "1", "--motion", "along", "--speed", "0.25", "--skew", "8", "--wind", "2",
                 "--white-balance-right", "1.1,1,0.9", "--jpeg-quality", "85", "--bag", str(bag_path),
                 "--compressed"]) == 0
    truths = [json.loads((out / f"frame_{k:04d}" / "truth.json").read_text()) for k in range(2)]
    assert [t["skew_ms"] for t in truths] == pytest.approx([8.0, 8.0])
    assert truths[1]["t_left"] == pytest.approx(1 / 15)
    assert truths[0]["sequence"]["motion"] == {"direction": "along", "speed_m_s": 0.25, "turn_rate_deg_s": 0.0}
    assert truths[0]["jpeg_quality"] == 85 and truths[1]["leaf_speed_mm_s"]["max"] > 0
    bag = BagReader(bag_path)
    assert set(bag.topics) == {"/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed",
                               "/truth/left/depth"}
    stamps = {}
    for topic in ("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed"):
        msgs = [m for _, m in bag.read(topic)]
        assert [m.format for m in msgs] == ["bgr8; jpeg compressed bgr8"] * 2
        img = cv2.imdecode(np.frombuffer(bytes(msgs[0].data), np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (120, 160, 3)
        stamps[topic] = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in msgs]
    skews = np.subtract(stamps["/stereo/right/image_raw/compressed"], stamps["/stereo/left/image_raw/compressed"])
    assert list(skews) == [8_000_000, 8_000_000]
    depths = read_truth_depths(bag_path)
    assert sorted(depths) == stamps["/stereo/left/image_raw/compressed"]
    _, rig = canopy_metadata(bag.metadata(), source=str(bag_path))
    assert rig is not None and rig.image_size == (160, 120)


@pytest.mark.parametrize("argv, message", [
    (["--motion", "along"], "--motion along needs --speed"),
    (["--speed", "0.2", "--motion", "still"], "--speed needs --motion"),
    (["--compressed"], "--compressed needs --bag"),
    (["--skew", "80"], "shorter than a frame period"),
    (["--white-balance-right", "1,0"], "--white-balance-right must be three positive numbers"),
])
def test_simulate_field_sequence_bad_options_are_one_line(tmp_path, small_rig_file, cli, argv, message):
    code, _, err = cli("simulate", "croton", "-o", str(tmp_path / "x"), "--rig", str(small_rig_file), *argv)
    assert code == 2 and message in err and "Traceback" not in err
