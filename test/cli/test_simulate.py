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
