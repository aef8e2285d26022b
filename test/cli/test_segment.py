"""``canopy-stereo segment``: a drawn scene (GrabCut rectangle, disparity seeds) and the synthetic
citrus branch (learned colour from the depth cue), against their truth masks; bad input."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.segmentation import read_mask
from canopy_stereo.sim import render_scene
from test.support.segmentation import blob_scene, iou, plant_truth, sim_depth


def test_cli_segment(tmp_path, cli):
    from canopy_stereo.io.pfm import write_pfm

    img, truth = blob_scene(leaf_bgr=(50, 60, 200))
    cv2.imwrite(str(tmp_path / "img.png"), img)
    code, out, err = cli("segment", tmp_path / "img.png", "--rect", "30,40,270,160", "-o", tmp_path / "r.png")
    assert code == 0, err
    assert iou(read_mask(tmp_path / "r.png"), truth) > 0.85
    disp = np.where(truth, 40.0, 12.0).astype(np.float32)
    disp[:3] = np.inf  # unknown
    write_pfm(tmp_path / "d.pfm", disp)
    code, out, err = cli("segment", tmp_path / "img.png", "--disparity", tmp_path / "d.pfm", "--index", "none",
                         "-o", tmp_path / "a.png")
    assert code == 0, err
    assert iou(read_mask(tmp_path / "a.png"), truth) > 0.95
    assert "% plant" in out
    # bad input: one line, exit 2
    code, out, err = cli("segment", tmp_path / "img.png", "--rect", "1,2,3", "-o", tmp_path / "x.png")
    assert code == 2 and "x,y,w,h" in err and len(err.strip().splitlines()) == 1
    code, out, err = cli("segment", tmp_path / "nope.png", "-o", tmp_path / "x.png")
    assert code == 2 and "not found" in err


@pytest.mark.slow
def test_cli_segment_citrus_learned_colour(tmp_path, cli):
    """`canopy-stereo segment --auto --index none --depth`: learned colour by default,
    the depth cue alone with --no-colour-model."""
    import cv2

    sim = render_scene("citrus_branch", seed=0)
    truth = plant_truth(sim)
    cv2.imwrite(str(tmp_path / "left.png"), sim.left)
    np.save(tmp_path / "dist.npy", sim_depth(sim, "elas", None))
    ious = {}
    for extra in ((), ("--no-colour-model",)):
        code, out, err = cli("segment", tmp_path / "left.png", "--depth", tmp_path / "dist.npy",
                             "--index", "none", *extra, "-o", tmp_path / "m.png")
        assert code == 0, err
        assert ("learned colour" in out) == (not extra)
        ious[extra] = iou(cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_GRAYSCALE) > 0, truth)
    assert ious[()] >= 0.93 and ious[("--no-colour-model",)] < 0.9
