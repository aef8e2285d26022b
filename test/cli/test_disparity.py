"""``canopy-stereo disparity`` and ``canopy-stereo eval-disparity``."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from canopy_stereo.elas.synthetic import shifted_pair
from canopy_stereo.io.pfm import read_pfm, write_pfm


@pytest.fixture
def pair_files(tmp_path):
    left, right, gt = shifted_pair(160, 120, shift=11.0, seed=7)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), right)
    # ground truth as a PNG with scale 4 (0 = unknown) and as a PFM (inf = unknown)
    png = np.where(np.isfinite(gt), np.rint(gt * 4), 0).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "gt.png"), png)
    write_pfm(tmp_path / "gt.pfm", np.where(np.isfinite(gt), gt, np.inf))
    return tmp_path


def test_disparity_writes_pfm_and_png(cli, pair_files):
    out = pair_files / "disp.pfm"
    code, stdout, err = cli("disparity", pair_files / "left.png", pair_files / "right.png",
                            "-o", out, "--disp-max", 40, "--png", pair_files / "vis.png")
    assert code == 0, err
    assert "density" in stdout
    disp = read_pfm(out)
    assert disp.shape == (120, 160) and disp.dtype == np.float32
    valid = np.isfinite(disp)
    assert not valid.all() and np.all(disp[~valid] == np.inf)        # invalid -> inf
    assert np.abs(disp[valid] - 11.0).max() <= 1.0
    from canopy_stereo.viz.colour import picture_offset

    vis = cv2.imread(str(pair_files / "vis.png"))
    y0, x0 = picture_offset((120, 160))
    assert vis.shape[0] > 120 + y0 - 1 and vis.shape[1] > 160  # the map, a title and a colour bar
    vis = vis[y0:y0 + 120, x0:x0 + 160]
    assert np.all(vis[~valid] == 0) and vis[valid].any()


@pytest.mark.parametrize("extra", [["--preset", "middlebury", "--subpixel"],
                                   ["--matcher", "sgbm"]])
def test_disparity_options(cli, pair_files, extra):
    out = pair_files / "d.pfm"
    code, _, err = cli("disparity", pair_files / "left.png", pair_files / "right.png",
                       "-o", out, "--disp-max", 47, *extra)
    assert code == 0, err
    disp = read_pfm(out)
    inner = disp[15:-15, 60:-15]      # SGBM leaves a band of disp_max+1 columns empty
    assert (np.abs(inner - 11.0) <= 1.0).mean() > 0.9


def test_eval_disparity_reports_the_scores(cli, pair_files):
    out = pair_files / "disp.pfm"
    assert cli("disparity", pair_files / "left.png", pair_files / "right.png", "-o", out,
               "--disp-max", 40)[0] == 0
    code, stdout, err = cli("eval-disparity", out, pair_files / "gt.png", "--gt-scale", 4,
                            "--json")
    assert code == 0, err
    scores = json.loads(stdout)
    assert scores["bad"]["2"] < 1.0 and scores["density"] > 70   # borders stay empty
    # PFM ground truth gives the same numbers; the text form names every statistic
    code, text, _ = cli("eval-disparity", out, pair_files / "gt.pfm")
    assert code == 0
    for key in ("bad>0.5", "bad>1", "bad>2", "bad>4", "density", "EPE", "bad>2 (all)"):
        assert key in text
    code, stdout, _ = cli("eval-disparity", out, pair_files / "gt.pfm", "--json")
    assert json.loads(stdout) == scores
    # a mask: only white pixels count
    mask = np.zeros((120, 160), np.uint8)
    mask[40:80, 60:100] = 255
    cv2.imwrite(str(pair_files / "mask.png"), mask)
    code, stdout, _ = cli("eval-disparity", out, pair_files / "gt.pfm", "--mask",
                          pair_files / "mask.png", "--json")
    masked = json.loads(stdout)
    assert masked["known"] == 1600 and masked["density"] == 100.0


def test_cli_errors_are_one_line(cli, pair_files, tmp_path):
    left, right = pair_files / "left.png", pair_files / "right.png"
    cases = [
        ("disparity", left, right, "-o", tmp_path / "x.pfm", "--disp-max", 5),
        ("disparity", left, right, "-o", tmp_path / "x.png"),
        ("disparity", left, tmp_path / "missing.png", "-o", tmp_path / "x.pfm"),
        ("disparity", left, right, "-o", tmp_path / "x.pfm", "--matcher", "sgbm", "--subpixel"),
        ("eval-disparity", pair_files / "gt.pfm", pair_files / "gt.png"),   # no --gt-scale
        ("eval-disparity", left, pair_files / "gt.pfm"),                    # not a PFM
    ]
    for args in cases:
        code, _, err = cli(*args)
        assert code == 2, args
        assert err.count("\n") == 1 and "error:" in err and "Traceback" not in err


def test_eval_disparity_size_mismatch(cli, pair_files):
    write_pfm(pair_files / "small.pfm", np.zeros((10, 10), np.float32))
    code, _, err = cli("eval-disparity", pair_files / "small.pfm", pair_files / "gt.pfm")
    assert code == 2 and "GT is 160x120" in err
