"""Disparity evaluation (canopy_stereo.disparity.metrics) on hand-made maps."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.disparity.metrics import evaluate_disparity, valid_disparity
from canopy_stereo.errors import CanopyStereoError


def _maps():
    gt = np.full((2, 5), 10.0)
    gt[1, 4] = np.nan                         # unknown ground truth
    disp = np.array([[10.0, 10.4, 10.8, 11.5, 13.0],
                     [-1.0, np.inf, 7.0, 10.0, 3.0]])
    return disp, gt


def test_scores_on_a_hand_made_map():
    disp, gt = _maps()
    s = evaluate_disparity(disp, gt)
    # evaluated: both valid and known -> (0,0..4), (1,2), (1,3) = 7 px
    # errors: 0, 0.4, 0.8, 1.5, 3.0, 3.0, 0
    assert s.evaluated == 7 and s.known == 9
    assert s.bad[0.5] == pytest.approx(100 * 4 / 7)
    assert s.bad[1.0] == pytest.approx(100 * 3 / 7)
    assert s.bad[2.0] == pytest.approx(100 * 2 / 7)
    assert s.bad[4.0] == 0.0
    assert s.epe == pytest.approx((0.4 + 0.8 + 1.5 + 3.0 + 3.0) / 7)
    # density over all 10 px: valid are 8 (the -1 and the inf are not)
    assert s.density == pytest.approx(80.0)
    # bad>2 counting invalid as wrong, over the 9 known pixels: 2 wrong + 2 invalid
    assert s.bad2_all == pytest.approx(100 * 4 / 9)


def test_mask_restricts_every_statistic():
    disp, gt = _maps()
    mask = np.zeros(disp.shape, bool)
    mask[0, :3] = True
    mask[1, 0] = True
    s = evaluate_disparity(disp, gt, mask=mask)
    assert s.evaluated == 3 and s.known == 4
    assert s.bad[0.5] == pytest.approx(100 / 3)
    assert s.density == pytest.approx(75.0)
    assert s.bad2_all == pytest.approx(25.0)


def test_perfect_map_and_empty_cases():
    gt = np.arange(12, dtype=float).reshape(3, 4)
    s = evaluate_disparity(gt.copy(), gt)
    assert all(v == 0 for v in s.bad.values()) and s.epe == 0 and s.density == 100
    s = evaluate_disparity(np.full((3, 4), -1.0), gt)
    assert s.evaluated == 0 and np.isnan(s.epe) and s.density == 0 and s.bad2_all == 100


def test_valid_disparity():
    d = np.array([0.0, -1.0, np.nan, np.inf, 3.5])
    assert valid_disparity(d).tolist() == [True, False, False, False, True]


def test_shape_mismatch_raises():
    with pytest.raises(CanopyStereoError, match="same size"):
        evaluate_disparity(np.zeros((3, 4)), np.zeros((4, 3)))
    with pytest.raises(CanopyStereoError, match="mask"):
        evaluate_disparity(np.zeros((3, 4)), np.zeros((3, 4)), mask=np.ones((2, 2), bool))


def test_format_and_dict():
    disp, gt = _maps()
    s = evaluate_disparity(disp, gt)
    text = s.format()
    assert "bad>2" in text and "density" in text and "EPE" in text
    d = s.as_dict()
    assert set(d["bad"]) == {"0.5", "1", "2", "4"}
