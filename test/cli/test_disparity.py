"""``canopy-stereo disparity`` (the pair files are the ``pair_files`` fixture of test/cli/conftest.py;
``eval-disparity`` is in test_eval_disparity.py, its bad input with the disparity cases below)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.io.pfm import read_pfm


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
@pytest.mark.slow
def test_disparity_options(cli, pair_files, extra):
    out = pair_files / "d.pfm"
    code, _, err = cli("disparity", pair_files / "left.png", pair_files / "right.png",
                       "-o", out, "--disp-max", 47, *extra)
    assert code == 0, err
    disp = read_pfm(out)
    inner = disp[15:-15, 60:-15]      # SGBM leaves a band of disp_max+1 columns empty
    assert (np.abs(inner - 11.0) <= 1.0).mean() > 0.9


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
