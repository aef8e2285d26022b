"""``canopy-stereo eval-disparity`` (the pair files are the ``pair_files`` fixture of test/cli/conftest.py)."""
from __future__ import annotations

import json

import cv2
import numpy as np

from canopy_stereo.io.pfm import write_pfm


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


def test_eval_disparity_size_mismatch(cli, pair_files):
    write_pfm(pair_files / "small.pfm", np.zeros((10, 10), np.float32))
    code, _, err = cli("eval-disparity", pair_files / "small.pfm", pair_files / "gt.pfm")
    assert code == 2 and "GT is 160x120" in err
