"""End to end: the foundation's reconstruction of a simulated croton is metric.

The simulator gives the exact world point behind every left pixel, so the
pipeline's organised cloud can be compared point by point with the truth.
"""
from dataclasses import replace

import numpy as np
import pytest

from canopy_stereo.disparity import available_matchers
from canopy_stereo.geometry.camera import point_depth
from canopy_stereo.pipeline.reconstruct import reconstruct_pair
from canopy_stereo.sim import render_scene


@pytest.fixture(scope="module")
def croton(paper_rig):
    return render_scene("croton", paper_rig, seed=0)


def depth_errors(sim, organized, mask):
    """Relative depth errors (left camera) of reconstructed pixels in ``mask`` and
    the fraction of ``mask`` that got a point."""
    got = mask & np.all(np.isfinite(organized), axis=2)
    P = sim.rig.P_left
    true_depth = point_depth(P, sim.xyz_left[got])
    rel = np.abs(point_depth(P, organized[got]) - true_depth) / true_depth
    return rel, got.sum() / mask.sum()


@pytest.mark.parametrize("matcher", ["sgbm", "elas"])
def test_reconstruction_of_croton_leaves_is_metric(croton, matcher):
    if matcher not in available_matchers():
        pytest.skip(f"matcher {matcher} is not available")
    sim = croton
    rec = reconstruct_pair(sim.left, sim.right, sim.rig, matcher=matcher)
    leaf = sim.leaf_ids_left > 0
    rel, coverage = depth_errors(sim, rec.organized, leaf)
    assert coverage >= 0.80
    assert np.median(rel) < 0.01
    # the two marked leaves, one by one
    for leaf_id in sim.truth["marked_leaf_ids"]:
        rel_leaf, cov_leaf = depth_errors(sim, rec.organized, sim.leaf_ids_left == leaf_id)
        assert cov_leaf >= 0.80
        assert np.median(rel_leaf) < 0.01
    # the metric scale is right, not only the shape: the median signed error is small
    got = leaf & np.all(np.isfinite(rec.organized), axis=2)
    scale = np.median(point_depth(sim.rig.P_left, rec.organized[got])
                      / point_depth(sim.rig.P_left, sim.xyz_left[got]))
    assert scale == pytest.approx(1.0, abs=0.005)


@pytest.mark.slow
def test_reconstruction_through_a_distorted_rig_is_metric(paper_rig):
    """The renderer's lens model and the pipeline's undistortion agree."""
    rig = replace(paper_rig, D_left=[-0.12, 0.05, 0.0008, -0.0005, 0.0],
                  D_right=[-0.10, 0.03, -0.0005, 0.0007, 0.0])
    sim = render_scene("croton", rig, seed=1)
    rec = reconstruct_pair(sim.left, sim.right, sim.rig, matcher="sgbm")
    rel, coverage = depth_errors(sim, rec.organized, sim.leaf_ids_left > 0)
    assert coverage >= 0.80
    assert np.median(rel) < 0.01
