"""Automatic plant masks on the synthetic scenes against their truth labels.

Truth: leaves, stems and fruit (labels 1, 2, 6). The depth cue is the
distance of the reconstructed points (reconstruct_pair) from the left camera.
Also the colour models learned from the depth cue (segmentation.colour_model).
"""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.segmentation import auto_plant_mask
from canopy_stereo.sim import render_scene
from test.support.segmentation import SGBM, iou, plant_truth, sim_depth


@pytest.mark.slow
def test_croton_colour_and_depth():
    """Red/yellow/green croton: depth finds what is near, ExG among the near
    pixels drops the terracotta pot and the soil."""
    sim = render_scene("croton", seed=0)
    truth = plant_truth(sim)
    mask = auto_plant_mask(sim.left, depth=sim_depth(sim), index="exg") > 0
    assert iou(mask, truth) >= 0.9
    # colour alone misses the orange and yellow parts
    assert iou(auto_plant_mask(sim.left, index="exg") > 0, truth) < iou(mask, truth)


@pytest.mark.slow
def test_seedling_tray_colour_only():
    sim = render_scene("seedling_tray", seed=0)
    mask = auto_plant_mask(sim.left, index="exg") > 0
    assert iou(mask, plant_truth(sim)) >= 0.9


@pytest.mark.slow
@pytest.mark.parametrize("matcher", ["elas", "sgbm"])
def test_citrus_branch_depth_and_learned_colour(matcher):
    """Green leaves before green foliage: no vegetation index helps, depth does,
    but the matcher fills the background gaps between leaves with the leaves'
    disparity. The colour models learned from the depth cue's sure pixels
    (default with index="none") remove those gaps."""
    sim = render_scene("citrus_branch", seed=1)
    truth = plant_truth(sim)
    params = None if matcher == "elas" else SGBM
    depth = sim_depth(sim, matcher, params)
    mask = auto_plant_mask(sim.left, depth=depth, index="none") > 0
    assert iou(mask, truth) >= 0.93
    # the depth votes alone keep the filled gaps (false plant)
    seed_only = auto_plant_mask(sim.left, depth=depth, index="none", refine=False, colour_model=False) > 0
    assert (seed_only & ~truth).sum() > 2 * (mask & ~truth).sum()
    # with the true depth the depth cue alone is exact
    true_depth = np.linalg.norm(sim.xyz_left - camera_centre(sim.rig.P_left), axis=-1)
    seed_only = auto_plant_mask(sim.left, depth=true_depth, index="none", refine=False, edge_px=0,
                                colour_model=False) > 0
    assert iou(seed_only, truth) >= 0.99


def test_colour_models_and_relabelling(rng):
    from canopy_stereo.errors import ImageError
    from canopy_stereo.segmentation.colour_model import fit_colour_gmm, relabel_by_colour
    from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD

    # two colour clusters: the mixture finds both, and its density is a density
    a = rng.normal((40, 80, 45), 3.0, (3000, 3))
    b = rng.normal((200, 190, 180), 6.0, (1000, 3))
    gmm = fit_colour_gmm(np.vstack([a, b]))
    assert gmm.weights.sum() == pytest.approx(1.0)
    big = np.argsort(gmm.weights)[::-1]
    for centre, share in (((40, 80, 45), 0.75), ((200, 190, 180), 0.25)):
        near = np.linalg.norm(gmm.means - centre, axis=1) < 10
        assert gmm.weights[near].sum() == pytest.approx(share, abs=0.01)
    assert gmm.log_likelihood(np.array([[40, 80, 45]])) > gmm.log_likelihood(np.array([[120, 120, 120]])) + 20
    g1 = fit_colour_gmm(a, components=1)
    x = np.array([[43.0, 80.0, 45.0]])
    cov = g1.covariances[0]
    expect = -0.5 * ((x - g1.means[0]) @ np.linalg.inv(cov) @ (x - g1.means[0]).T).item() \
        - 0.5 * np.log(np.linalg.det(cov)) - 1.5 * np.log(2 * np.pi)
    assert g1.log_likelihood(x)[0] == pytest.approx(expect)
    model = gmm.grabcut_model()
    assert model.shape == (1, 65) and model[0, :5].sum() == pytest.approx(1.0)
    assert np.allclose(model[0, 5 + 3 * big[0]:8 + 3 * big[0]], gmm.means[big[0]])
    with pytest.raises(ImageError, match="too few pixels"):
        fit_colour_gmm(a[:10])
    # relabelling rules (sure log ratio 3)
    labels = np.array([[GC_FGD, GC_FGD, GC_FGD, GC_PR_FGD, GC_PR_BGD, GC_PR_BGD, GC_PR_BGD, GC_BGD]],
                      np.uint8)
    llr = np.array([[5.0, 1.0, -1.0, -5.0, 5.0, 1.0, -5.0, 9.0]])
    assert relabel_by_colour(labels, llr, sure=3.0).tolist() == [
        [GC_FGD, GC_PR_FGD, GC_PR_BGD, GC_BGD, GC_PR_FGD, GC_PR_BGD, GC_BGD, GC_BGD]]


@pytest.mark.slow
def test_colour_model_needs_a_depth_cue_and_no_index():
    from canopy_stereo.errors import ImageError

    sim = render_scene("seedling_tray", seed=0)
    with pytest.raises(ImageError, match="learns from the depth cue"):
        auto_plant_mask(sim.left, index="none", colour_model=True)
    depth = np.where(plant_truth(sim), 500.0, 900.0)
    with pytest.raises(ImageError, match="use index='none'"):
        auto_plant_mask(sim.left, depth=depth, index="exg", colour_model=True)
    tiny = np.where(np.arange(depth.size).reshape(depth.shape) < 20, 500.0, 900.0)  # 20 near pixels
    with pytest.raises(ImageError, match="too few sure pixels"):
        auto_plant_mask(sim.left, depth=tiny, index="none", colour_model=True)
