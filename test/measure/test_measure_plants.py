"""Per-plant measurement: height from the pot rim (or soil), the pot not measured, plants apart."""
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.measure import measure_plants
from canopy_stereo.sim import CLEAN, render_scene, rig_at_resolution


@pytest.fixture(scope="module")
def two_pots(paper_rig):
    return render_scene("pots_side_by_side", rig_at_resolution(paper_rig, 0.5), effects=CLEAN, supersample=1)


@pytest.mark.slow
def test_heights_from_the_pot_rim_on_the_exact_cloud(two_pots):
    sim = two_pots
    res = measure_plants(sim.xyz_left, sim.plants_left.astype(np.int32), camera=sim.rig.P_left,
                         separate=False)
    assert res["n_plants"] == 2
    for rep, truth in zip(res["plants"], sim.truth["plants"]):
        assert rep["plant_index"] == truth["index"]
        assert rep["reference"]["kind"] == "pot_rim"
        assert rep["frame"]["kind"] == "ground"  # the table top
        can = rep["canopy"]
        assert can["height"] == pytest.approx(truth["height"], rel=0.02)
        # the rim lies about 110 mm (the pot) above the table; the plant's own extent starts at the soil
        assert rep["reference"]["height_above_ground"] == pytest.approx(110.0, abs=4.0)
        assert can["bbox_min"][2] > 95.0 and can["extent_height"] < truth["height"] + 12.0


def test_measure_plants_rejects_bad_instances(two_pots):
    sim = two_pots
    with pytest.raises(CanopyStereoError, match="all 0"):
        measure_plants(sim.xyz_left, np.zeros(sim.plants_left.shape, np.int32))
    with pytest.raises(CanopyStereoError, match="integer"):
        measure_plants(sim.xyz_left, sim.plants_left.astype(float))
    with pytest.raises(CanopyStereoError, match="like the cloud"):
        measure_plants(sim.xyz_left, sim.plants_left[:10].astype(np.int32))


@pytest.mark.slow
def test_seedling_heights_above_the_tray_from_a_top_view(paper_rig):
    """Each seedling of the tray (true instances, exact cloud, ground="view"): its height above the
    soil of the tray, which a top view sees around the leaves, not under them, measured along the
    soil's normal (the tray need not face the camera squarely): within 2 % of the truth for every
    seedling wholly in view; those cut by the image border are flagged."""
    sim = render_scene("seedling_tray", paper_rig, effects=CLEAN, supersample=1)
    inst = sim.plants_left.astype(np.int32)
    counts = np.bincount(inst.ravel())
    inst[counts[inst] < 50] = 0  # seedlings barely in view
    res = measure_plants(sim.xyz_left, inst, camera=sim.rig.P_left, ground="view", separate=False)
    errors = {}
    for rep in res["plants"]:
        assert rep["reference"]["kind"] == "soil"
        k = rep["plant_index"]
        pixels = inst == k
        assert rep["at_image_border"] == bool(pixels[0].any() or pixels[-1].any() or pixels[:, 0].any()
                                              or pixels[:, -1].any())
        truth = sim.truth["plants"][k - 1]["height"]
        if not rep["at_image_border"]:
            errors[k] = rep["canopy"]["height"] / truth - 1.0
    assert len(errors) > 25
    assert max(abs(e) for e in errors.values()) <= 0.02, errors


def test_trim_keeps_the_far_side_and_drops_background_on_the_rim():
    """trimmed_mask on rays of a pinhole camera (exact distances, mm): a plant at 600 mm keeps,
    beyond 1.2 x its median distance but much nearer it than the backdrop at 1000 mm, a leaf
    750 mm away seen through a gap and the far end of a leaf receding to 770 mm at its right rim;
    the plant's rim given the backdrop's depth (the matcher's debris) or a blend nearer it
    (900 mm) is dropped."""
    from canopy_stereo.measure.plants import trimmed_mask

    h = w = 120
    K = np.array([[300.0, 0, w / 2], [0, 300.0, h / 2], [0, 0, 1]])
    P = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    v, u = np.mgrid[0:h, 0:w]
    rays = np.stack([(u - w / 2) / 300.0, (v - h / 2) / 300.0, np.ones((h, w))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    r = np.hypot(u - w / 2, v - h / 2)
    mask = r <= 40
    dist = np.full((h, w), 1000.0)  # the backdrop
    dist[mask] = 600.0
    gap = np.hypot(u - 70, v - 60) <= 6  # the far leaf seen through a gap in the canopy
    dist[gap] = 750.0
    receding = mask & (u >= 90)
    dist[receding] = 600.0 + (u[receding] - 90) * 17.0  # 736-770 mm at u 98-100
    debris = mask & (r > 38) & (u < 50)  # the left rim at the backdrop's depth
    dist[debris] = 1000.0
    blend = mask & (r > 38) & (v < 40) & (u >= 50) & (u < 80)  # the top rim: a leaf/backdrop blend
    dist[blend] = 900.0
    organized = rays * dist[..., None]
    kept = trimmed_mask(organized, mask, camera=P)
    assert kept[gap].all() and kept[receding].all() and (dist[receding] > 720).sum() >= 9
    assert not kept[debris].any() and not kept[blend].any()
    assert (kept == (mask & ~debris & ~blend)).all()
    assert (trimmed_mask(organized, mask, camera=None) == mask).all()


def test_group_medians_match_numpy_per_label():
    from canopy_stereo.measure.plants import _group_medians

    rng = np.random.default_rng(3)
    values = rng.normal(size=(40, 50))
    labels = rng.integers(0, 7, size=(40, 50))
    labels[labels == 5] = 0  # label 5 without pixels
    out = _group_medians(values, labels, 6)
    for k in range(1, 7):
        expected = np.median(values[labels == k]) if (labels == k).any() else np.nan
        np.testing.assert_allclose(out[k - 1], expected, equal_nan=True)
