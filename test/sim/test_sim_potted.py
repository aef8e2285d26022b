"""Scenes that test a plant mask: distractors (a green watering can, a pot with soil, a green
stake, a green box), plants that are not green, several plants, per-plant truth."""
import cv2
import numpy as np
import pytest

from canopy_stereo.sim import CLEAN, build_scene, render_scene, rig_at_resolution
from canopy_stereo.sim.primitives import LABEL_LEAF, LABEL_OBJECT, LABEL_POT, LABEL_SOIL


@pytest.fixture(scope="module")
def half_rig(paper_rig):
    return rig_at_resolution(paper_rig, 0.5)


def test_potted_distractors_show_every_distractor_and_one_plant(half_rig):
    sim = render_scene("potted_distractors", half_rig, effects=CLEAN, supersample=1)
    counts = np.bincount(sim.labels_left.ravel(), minlength=8)
    for label in (LABEL_LEAF, LABEL_POT, LABEL_SOIL, LABEL_OBJECT):
        assert counts[label] > 200, label
    plants = sim.truth["plants"]
    assert [p["index"] for p in plants] == [1] and plants[0]["reference"] == "pot_rim"
    assert 200 < plants[0]["height"] < 340  # mm above the pot rim
    # the plant pixels are exactly its leaves and stems
    plant = sim.plants_left == 1
    assert np.all(np.isin(sim.labels_left[plant], (1, 2)))
    # the distractors are green: a vegetation index does not tell them from the plant
    hsv = cv2.cvtColor(sim.left, cv2.COLOR_BGR2HSV)
    assert 35 <= np.median(hsv[..., 0][sim.labels_left == LABEL_OBJECT]) <= 85


def test_two_plants_side_by_side_are_not_green_and_numbered_left_to_right(half_rig):
    for seed in (0, 1):
        sim = render_scene("pots_side_by_side", half_rig, seed=seed, effects=CLEAN, supersample=1)
        plants = sim.truth["plants"]
        assert [p["index"] for p in plants] == [1, 2]
        cols = [np.nonzero(sim.plants_left == k)[1].mean() for k in (1, 2)]
        assert cols[0] < cols[1]
        for p in plants:
            assert 180 < p["height"] < 320
        b, g, r = (sim.left[sim.labels_left == LABEL_LEAF].astype(float).mean(0))
        assert not (g > 1.3 * r and g > 1.3 * b)  # the foliage is not green


def test_plant_truth_moves_with_the_rig_and_frame(paper_rig):
    scene = build_scene("pots_side_by_side", 0)
    heights = [p["height"] for p in scene.plants_truth()]
    from canopy_stereo.sim import place_in_front_of

    placed = place_in_front_of(scene, paper_rig)
    assert [p["height"] for p in placed.plants_truth()] == pytest.approx(heights, rel=1e-9)
    swayed = [p["height"] for p in scene.at_frame(7).plants_truth()]
    assert swayed != heights and swayed == pytest.approx(heights, rel=0.05)


def test_seedling_tray_has_one_plant_per_seedling():
    scene = build_scene("seedling_tray", 0)
    truth = scene.plants_truth()
    assert len(truth) > 30 and all(p["reference"] == "soil" for p in truth)
    assert all(9.0 < p["height"] < 45.0 for p in truth)
    ids = [i for p in truth for i in p["leaf_ids"]]
    assert sorted(ids) == sorted(lf.leaf_id for lf in scene.leaves)
