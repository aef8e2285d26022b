"""The rectify and reconstruct commands, including bad input (calibrate: test_calibrate.py)."""
import numpy as np
import pytest

from canopy_stereo.io.ply import read_ply
from test.conftest import REPO, run_cli_subprocess


def test_rectify_and_reconstruct_bundled_pair(cli, tmp_path):
    left, right = REPO / "examples/plants/left.png", REPO / "examples/plants/right.png"
    rig = REPO / "config/plants_rig.yaml"
    code, out, err = cli("rectify", left, right, "--rig", rig, "-o", tmp_path / "rect")
    assert code == 0, err
    assert (tmp_path / "rect/left_rect.png").is_file() and (tmp_path / "rect/rig_fusiello.yaml").is_file()
    code, out, err = cli("reconstruct", left, right, "--rig", rig, "-o", tmp_path / "c.ply",
                         "--organized", tmp_path / "org.npy")
    assert code == 0, err
    assert "bounding box (mm)" in out and "time per stage" in out
    cloud = read_ply(tmp_path / "c.ply")
    assert cloud.unit == "mm" and len(cloud) > 100000
    org = np.load(tmp_path / "org.npy")
    assert org.shape == (496, 710, 3)
    z = cloud.points[:, 2]
    # the plant stands roughly 1.8-3 m from the Middlebury rig
    assert 1500 < np.median(z) < 3500


def _bad_rig(tmp_path, P_right):
    p = tmp_path / "bad.yaml"
    p.write_text("/**:\n  ros__parameters:\n    image_width: 640\n    image_height: 480\n"
                 "    P_left: [600,0,320,0, 0,600,240,0, 0,0,1,0]\n"
                 f"    P_right: {P_right}\n")
    return p


@pytest.mark.slow
@pytest.mark.parametrize("case", ["sizes", "unreadable", "nonfinite", "rank"])
def test_bad_input_one_line_no_traceback(tmp_path, case):
    import cv2

    a = tmp_path / "a.png"
    b = tmp_path / "b.png"
    cv2.imwrite(str(a), np.zeros((480, 640, 3), np.uint8))
    cv2.imwrite(str(b), np.zeros((240, 320, 3), np.uint8))
    rig = REPO / "config/paper_rig.yaml"
    if case == "sizes":
        args, word = ("reconstruct", a, b, "--rig", rig, "-o", tmp_path / "c.ply"), "sizes differ"
    elif case == "unreadable":
        (tmp_path / "junk.png").write_bytes(b"junk")
        args, word = ("reconstruct", a, tmp_path / "junk.png", "--rig", rig, "-o", tmp_path / "c.ply"), "cannot read"
    elif case == "nonfinite":
        args, word = ("reconstruct", a, a, "--rig", _bad_rig(tmp_path, "[.nan,0,0,0, 0,1,0,0, 0,0,1,0]"),
                      "-o", tmp_path / "c.ply"), "non-finite"
    else:  # rank
        args, word = ("reconstruct", a, a, "--rig", _bad_rig(tmp_path, "[1,0,0,0, 0,1,0,0, 0,0,0,1]"),
                      "-o", tmp_path / "c.ply"), "rank"
    res = run_cli_subprocess(*args)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert word in lines[0] and "Traceback" not in res.stderr


@pytest.mark.slow
def test_reconstruct_and_measure_croton(cli, tmp_path):
    """reconstruct --measure on the synthetic croton: marked leaves within 2 % of truth."""
    import json

    sim = tmp_path / "sim"
    code, _, err = cli("simulate", "croton", "-o", sim, "--seed", "2")
    assert code == 0, err
    code, out, err = cli("reconstruct", sim / "left.png", sim / "right.png", "--rig", sim / "rig.yaml",
                         "-o", tmp_path / "c.ply", "--measure", "--leaf-ids", sim / "leaf_ids_left.png",
                         "--report", tmp_path / "r.json", "--csv", tmp_path / "l.csv")
    assert code == 0, err
    report = json.loads((tmp_path / "r.json").read_text())
    truth = json.loads((sim / "truth.json").read_text())
    assert report["unit"] == "mm"
    by_id = {lf["id"]: lf for lf in report["leaves"]}
    for leaf in (lf for lf in truth["leaves"] if lf["marked"]):
        got = by_id[leaf["id"]]
        assert abs(got["length"] / leaf["length"] - 1) < 0.02
        assert abs(got["width"] / leaf["width"] - 1) < 0.02
    assert (tmp_path / "l.csv").read_text().count("\n") >= 3
    code, _, err = cli("reconstruct", sim / "left.png", sim / "right.png", "--rig", sim / "rig.yaml",
                       "-o", tmp_path / "c.ply", "--measure")
    assert code == 2 and "--report" in err
