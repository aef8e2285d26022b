"""The calibrate command (points, chessboard, the paper layout), including bad input (``--world-rig``
from rendered images: test/geometry/test_world_rig.py, beside its rendering)."""
import numpy as np
import pytest

from canopy_stereo.geometry.board_placements import paper_layout_placements
from canopy_stereo.geometry.camera import camera_centre, project
from canopy_stereo.io.placements import load_placements
from canopy_stereo.io.rig import load_rig
from test.conftest import run_cli_subprocess


def _write_points_csv(path, rig, rng, n_planes=3):
    X = np.array([[x, y, z] for z in (450.0, 600.0, 750.0)[:n_planes]
                  for x in np.arange(-150, 251, 50.0) for y in np.arange(-200, 101, 50.0)])
    xl = project(rig.P_left, X) + rng.normal(0, 0.2, (len(X), 2))
    xr = project(rig.P_right, X) + rng.normal(0, 0.2, (len(X), 2))
    rows = ["X,Y,Z,u_left,v_left,u_right,v_right"]
    rows += [",".join(f"{v:.6f}" for v in r) for r in np.hstack([X, xl, xr])]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.slow
def test_calibrate_points(cli, tmp_path, paper_rig, rng):
    csv = _write_points_csv(tmp_path / "pts.csv", paper_rig, rng)
    code, out, err = cli("calibrate", "--points", csv, "-o", tmp_path / "rig.yaml", "--plot", tmp_path / "e.png")
    assert code == 0, err
    assert "reprojection RMS" in out and "mean |X_act - X_est|" in out
    rig = load_rig(tmp_path / "rig.yaml")
    assert np.linalg.norm(camera_centre(rig.P_left) - camera_centre(paper_rig.P_left)) < 1.0
    assert (tmp_path / "e.png").stat().st_size > 1000


def test_calibrate_chessboard(cli, tmp_path, shared_data):
    d = shared_data / "opencv_stereo_calib_chessboard"
    code, out, err = cli("calibrate", "--chessboard", d / "left*.jpg", d / "right*.jpg", "--pattern", "9x6",
                         "--square", "25", "-o", tmp_path / "rig.yaml")
    assert code == 0, err
    rms = float(out.split("stereo RMS ")[1].split()[0])
    assert rms <= 0.5
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.has_distortion and rig.image_size == (640, 480)
    # the working distance it saw (the boards stand 0.34 to 0.47 m away), with margin
    assert 0.1 < rig.extra["near_m"] < 0.3 and 0.6 < rig.extra["far_m"] < 1.5 and "working distance" in out


@pytest.mark.slow
def test_the_board_a_calibration_saw_is_reconstructed(cli, tmp_path, shared_data):
    """Issue 23: with the old default range (beyond 8 baselines, 669 mm) the board 340-410 mm
    away went missing without a word; the range calibrate writes covers it, and the old
    range now warns, naming the range and how to widen it."""
    from canopy_stereo.io.ply import read_ply

    d = shared_data / "opencv_stereo_calib_chessboard"
    code, out, err = cli("calibrate", "--chessboard", d / "left*.jpg", d / "right*.jpg", "--pattern", "9x6",
                         "--square", "25", "-o", tmp_path / "rig.yaml")
    assert code == 0, err
    code, out, err = cli("reconstruct", d / "left01.jpg", d / "right01.jpg", "--rig", tmp_path / "rig.yaml",
                         "-o", tmp_path / "c.ply")
    assert code == 0, err
    z = read_ply(tmp_path / "c.ply").points[:, 2]
    # nothing nearer than the range (the room behind the board is farther: a warning may say so)
    assert np.sum((z > 300) & (z < 450)) > 5000 and "largest disparity" not in err
    rig = load_rig(tmp_path / "rig.yaml")
    old = rig.with_extra(near_m=None, far_m=None)
    old.extra.pop("near_m"), old.extra.pop("far_m")
    from canopy_stereo.io.rig import save_rig

    save_rig(old, tmp_path / "old.yaml")
    code, out, err = cli("reconstruct", d / "left01.jpg", d / "right01.jpg", "--rig", tmp_path / "old.yaml",
                         "-o", tmp_path / "o.ply")
    assert code == 0, err
    z = read_ply(tmp_path / "o.ply").points[:, 2]
    assert np.sum((z > 300) & (z < 450)) < 500
    assert "largest disparity searched" in err and "--near" in err and "near_m" in err



@pytest.mark.slow
@pytest.mark.parametrize("case", ["few", "coplanar"])
def test_bad_input_one_line_no_traceback(tmp_path, paper_rig, rng, case):
    if case == "few":
        csv = tmp_path / "p.csv"
        csv.write_text("X,Y,Z,u_left,v_left,u_right,v_right\n" + "1,2,3,4,5,6,7\n" * 5)
        args, word = ("calibrate", "--points", csv, "-o", tmp_path / "r.yaml"), "at least 6"
    else:
        csv = _write_points_csv(tmp_path / "p.csv", paper_rig, rng, n_planes=1)
        args, word = ("calibrate", "--points", csv, "-o", tmp_path / "r.yaml"), "coplanar"
    res = run_cli_subprocess(*args)
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert word in lines[0] and "Traceback" not in res.stderr


def test_cli_paper_layout_writes_the_45_placements(tmp_path, cli):
    code, out, err = cli("calibrate", "--paper-layout", "-o", tmp_path / "layout.yaml")
    assert code == 0, err
    pl = load_placements(tmp_path / "layout.yaml")
    ref = paper_layout_placements()
    assert len(pl) == 45 and pl.pattern == (7, 5) and pl.square == 50.0
    assert all(np.allclose(a.origin, b.origin, atol=1e-3) for a, b in zip(pl, ref))
    code, out, err = cli("calibrate", "--paper-layout", "--first-mark", "600", "--marks-per-line", "5",
                         "--line-angles=-15,15", "-o", tmp_path / "l2.yaml")
    assert code == 0, err
    pl2 = load_placements(tmp_path / "l2.yaml")
    assert len(pl2) == 10
    assert np.isclose(np.degrees(np.arctan2(pl2[0].x_axis[2], pl2[0].x_axis[0])), 15.0)
