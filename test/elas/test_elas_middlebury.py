"""ELAS on the Middlebury 2001/2003 pairs in ../shared/data against the reference figures
of libelas (elas.md, section 9): bad>2 and density within 1 point, both presets."""
from __future__ import annotations

import pytest

from canopy_stereo.disparity.metrics import evaluate_disparity
from canopy_stereo.elas import elas_disparity
from canopy_stereo.io.images import read_image
from canopy_stereo.io.middlebury import read_disparity

# name: (folder, left, right, ground truth, PNG scale)
PAIRS = {
    "tsukuba": ("middlebury2001/Tsukuba", "imL.png", "imR.png", "truedisp.pgm", 16),
    "venus": ("middlebury2001/Venus", "imL.png", "imR.png", "disp2.pgm", 8),
    "teddy": ("middlebury2003_quartersize/Teddy", "imL.png", "imR.png", "disp2.png", 4),
    "cones": ("middlebury2003_quartersize/Cones", "imL.png", "imR.png", "disp2.png", 4),
}

# libelas (bad>2 %, density %) per preset, on pixels where both have a value
REFERENCE = {
    ("tsukuba", "robotics"): (4.0, 86.0), ("tsukuba", "middlebury"): (4.5, 100.0),
    ("venus", "robotics"): (2.3, 90.0), ("venus", "middlebury"): (3.5, 100.0),
    ("teddy", "robotics"): (6.5, 80.0), ("teddy", "middlebury"): (14.6, 100.0),
    ("cones", "robotics"): (4.1, 80.0), ("cones", "middlebury"): (10.7, 100.0),
}


@pytest.fixture(scope="module")
def pairs(shared_data):
    out = {}
    for name, (folder, left, right, gt, scale) in PAIRS.items():
        base = shared_data / folder
        out[name] = (read_image(base / left, color=False), read_image(base / right, color=False),
                     read_disparity(base / gt, scale))
    return out


@pytest.mark.shared
@pytest.mark.parametrize("preset", ["robotics", "middlebury"])
@pytest.mark.parametrize("name", list(PAIRS))
def test_matches_the_libelas_reference(pairs, name, preset):
    left, right, gt = pairs[name]
    disp, _ = elas_disparity(left, right, preset=preset)          # defaults: disp 0..255
    scores = evaluate_disparity(disp, gt)
    ref_bad2, ref_density = REFERENCE[(name, preset)]
    assert abs(scores.bad[2.0] - ref_bad2) <= 1.0, scores.format()
    assert abs(scores.density - ref_density) <= 1.0, scores.format()
