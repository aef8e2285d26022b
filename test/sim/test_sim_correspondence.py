"""Exact correspondences of rendered pairs and the study's correctness against them."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.study import correspondence_correctness, run_study
from canopy_stereo.geometry.camera import project
from canopy_stereo.sim import render_scene
from canopy_stereo.sim.correspondence import true_right_pixels


@pytest.fixture(scope="module")
def croton():
    sim = render_scene("croton", seed=0)
    return sim, true_right_pixels(sim)


def test_true_right_pixels_see_the_same_point(croton):
    sim, truth = croton
    h, w = truth.shape[:2]
    known = np.all(np.isfinite(truth), axis=2)
    assert 0.5 < known.mean() < 1.0                          # occlusions and borders drop out
    # the point the right image sees at the true pixel is the left pixel's point
    v, u = np.nonzero(known)
    tr = truth[v, u]
    ui, vi = np.rint(tr[:, 0]).astype(int), np.rint(tr[:, 1]).astype(int)
    d = np.linalg.norm(sim.xyz_right[vi, ui] - sim.xyz_left[v, u], axis=1)
    assert np.median(d) < 1.0 and d.max() < 2.0              # mm: half a pixel of rounding
    assert np.allclose(project(sim.rig.P_right, sim.xyz_left[v[:10], u[:10]]), tr[:10])
    # nothing where the left pixel sees nothing
    assert not known[~np.all(np.isfinite(sim.xyz_left), axis=2)].any()


def test_correspondence_correctness_scores_exact_and_shifted_matches(croton):
    _, truth = croton
    v, u = np.mgrid[40:440:20, 40:600:20]
    xl = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    xr = truth[v.ravel(), u.ravel()]
    ok = np.all(np.isfinite(xr), axis=1)
    share, n = correspondence_correctness(xl, xr, truth)
    assert share == 1.0 and n == ok.sum()
    share, _ = correspondence_correctness(xl, xr + [0.0, 1.5], truth)
    assert share == 0.0
    half = xr.copy()
    half[::2] += [3.0, 0.0]
    share, _ = correspondence_correctness(xl[ok], half[ok], truth)
    assert 0.4 < share < 0.6
    assert correspondence_correctness(np.zeros((0, 2)), np.zeros((0, 2)), truth) == (None, 0)
    with pytest.raises(CanopyStereoError):
        correspondence_correctness(xl, xr, truth[..., 0])


@pytest.mark.slow
def test_study_rows_against_exact_correspondences(croton):
    sim, truth = croton
    rows = run_study(sim.left, sim.right, methods=["sift", "qdmatch"], gt_right_pixels=truth)
    assert [r.correct_basis for r in rows] == ["gt", "gt"]
    for r in rows:
        assert r.correct >= 0.95 and r.n_evaluated > 0.9 * r.result.num
    assert rows[1].result.distribution > 3 * rows[0].result.distribution
    with pytest.raises(CanopyStereoError):
        run_study(sim.left, sim.right, methods=["sift"], gt_disparity=np.zeros(sim.left.shape[:2]),
                  gt_right_pixels=truth)
