"""Feature matching on the shared Middlebury data (skipped without ../shared/data)."""
from __future__ import annotations

import pytest

from canopy_stereo.features import match_pair
from canopy_stereo.features.study import gt_correctness, run_study
from canopy_stereo.io.images import read_image
from canopy_stereo.io.middlebury import read_disparity

GT_PAIRS = {
    # name: (folder, left, right, gt, scale)
    "Aloe": ("middlebury2006_thirdsize/Aloe", "view1.png", "view5.png", "disp1.png", 3),
    "Cones": ("middlebury2003_quartersize/Cones", "imL.png", "imR.png", "disp2.png", 4),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(GT_PAIRS))
def test_qdmatch_is_correct_and_spreads_wider_than_sift(shared_data, name):
    folder, left_file, right_file, truth_file, scale = GT_PAIRS[name]
    left = read_image(shared_data / folder / left_file)
    right = read_image(shared_data / folder / right_file)
    gt = read_disparity(shared_data / folder / truth_file, scale)
    qd = match_pair(left, right, method="qdmatch")
    sift = match_pair(left, right, method="sift")
    share, n = gt_correctness(qd.x_left, qd.x_right, gt)
    assert n > 0.9 * qd.num and qd.num > 500
    assert share >= 0.95
    assert qd.distribution > sift.distribution


def test_study_without_gt_on_the_plants_scene(shared_data):
    folder = shared_data / "middlebury_MiddEval3_testQ" / "Plants"
    left, right = read_image(folder / "im0.png"), read_image(folder / "im1.png")
    rows = run_study(left, right, methods=["sift", "qdmatch"])
    assert [r.correct_basis for r in rows] == ["epipolar", "epipolar"]
    sift, qd = rows
    assert qd.result.num > sift.result.num
    assert qd.correct >= 0.9 and sift.correct >= 0.9
    assert qd.result.distribution > sift.result.distribution


@pytest.mark.slow
def test_qdmatch_reaches_the_paper_spread_on_plant_pairs(shared_data):
    """Issue 18: qdmatch covered 13.4 % of the cells of Plants and 47.5 % of Aloe; the
    paper's qdmatch covers 27-31 %. Reseeding + centroid resampling reach the leaves;
    the aperture and interior checks keep Middlebury >= 95 % correct while a lower texture
    threshold lets the propagation cover weakly textured leaves and pots."""
    folder = shared_data / "middlebury_MiddEval3_testQ" / "Plants"
    left, right = read_image(folder / "im0.png"), read_image(folder / "im1.png")
    rows = run_study(left, right, methods=["sift", "qdmatch"])
    sift, qd = rows
    assert qd.result.distribution >= 0.26                    # paper: 27-31 %
    assert 1300 <= qd.result.num <= 1800                      # paper: 1400-1600 matches
    assert qd.result.distribution > 3 * sift.result.distribution
    assert qd.correct >= 0.95
    assert qd.result.extras["num_propagated"] > 60000
    folder, left_file, right_file, truth_file, scale = GT_PAIRS["Aloe"]
    left = read_image(shared_data / folder / left_file)
    right = read_image(shared_data / folder / right_file)
    gt = read_disparity(shared_data / folder / truth_file, scale)
    qd = match_pair(left, right, method="qdmatch")
    share, _ = gt_correctness(qd.x_left, qd.x_right, gt)
    assert qd.distribution >= 0.55 and share >= 0.98


#: Every Middlebury pair with ground truth in ../shared/data: (folder, left, right, gt, scale).
MIDDLEBURY_GT = {
    "Tsukuba": ("middlebury2001/Tsukuba", "imL.png", "imR.png", "truedisp.pgm", 16),
    "Venus": ("middlebury2001/Venus", "imL.png", "imR.png", "disp2.pgm", 8),
    "Cones": ("middlebury2003_quartersize/Cones", "imL.png", "imR.png", "disp2.png", 4),
    "Teddy": ("middlebury2003_quartersize/Teddy", "imL.png", "imR.png", "disp2.png", 4),
    "Aloe": GT_PAIRS["Aloe"],
    "Flowerpots": ("middlebury2006_thirdsize/Flowerpots", "view1.png", "view5.png", "disp1.png", 3),
    **{f"Q{s}": (f"middlebury_MiddEval3_trainingQ/{s}", "im0.png", "im1.png", "disp0GT.pfm", None)
       for s in ("Adirondack", "ArtL", "Motorcycle", "Piano", "Playtable", "Recycle", "Shelves",
                 "Teddy", "Vintage")},
}


@pytest.mark.slow
def test_qdmatch_is_95_percent_correct_on_the_middlebury_scenes(shared_data):
    """Issue 18: reseeding and relaxed resampling had let qdmatch fall to 90.7 % correct
    on average (73.7 % on Playtable); the aperture and interior checks bring the mean
    back above 95 % (96.5 %; 13 of 15 scenes >= 95 %, Playtable 91 %) with every scene
    above 90 % and wider spread than SIFT everywhere."""
    shares = {}
    for name, (folder, left_file, right_file, truth_file, scale) in MIDDLEBURY_GT.items():
        left = read_image(shared_data / folder / left_file)
        right = read_image(shared_data / folder / right_file)
        gt = read_disparity(shared_data / folder / truth_file, scale)
        qd = match_pair(left, right, method="qdmatch")
        sift = match_pair(left, right, method="sift")
        shares[name], n = gt_correctness(qd.x_left, qd.x_right, gt)
        assert n > 0.8 * qd.num, name
        assert qd.distribution > sift.distribution, name
    assert sum(shares.values()) / len(shares) >= 0.95, shares
    assert min(shares.values()) >= 0.90, shares
    assert sum(s >= 0.95 for s in shares.values()) >= 12, shares
