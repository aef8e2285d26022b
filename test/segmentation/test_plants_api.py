"""segment_plants: inputs checked, plants numbered left to right, sticks dropped."""
import numpy as np
import pytest

from canopy_stereo.errors import ImageError
from canopy_stereo.segmentation import PLANT_SEGMENTER, plant_instances, segment_plants
from canopy_stereo.segmentation.shape import fit_planes, inverse_depth, local_roughness


def test_instances_are_numbered_left_to_right_and_near_parts_join():
    m = np.zeros((100, 200), bool)
    m[10:40, 150:180] = True   # right plant
    m[10:40, 20:50] = True     # left plant, two parts 2 px apart
    m[42:60, 20:50] = True
    q = np.full(m.shape, 30.0)
    inst, plants = plant_instances(m, q)
    assert [p["plant_index"] for p in plants] == [1, 2]
    assert inst[20, 30] == 1 and inst[50, 30] == 1 and inst[20, 160] == 2
    assert plants[0]["bbox"] == [20, 10, 30, 50] and plants[1]["pixels"] == 900
    # parts at very different depths are different plants
    q[42:60, 20:50] = 10.0
    _, plants = plant_instances(m, q)
    assert len(plants) == 3


def test_planes_and_roughness_of_an_inverse_depth_map():
    h, w = 120, 160
    v, u = np.mgrid[0:h, 0:w].astype(float)
    q = 10.0 + 0.01 * u                      # backdrop
    table = v > 80
    q[table] = (0.8 * v - 50.0)[table]      # a table seen from above
    rng = np.random.default_rng(0)
    leaves = (np.abs(u - 60) < 12) & (v > 20) & (v < 70)
    q[leaves] = 40.0 + rng.uniform(-4, 4, leaves.sum())
    planes = fit_planes(q, tolerance=0.5)
    assert len(planes) == 2
    assert sum(p.is_ground(float(np.median(q)), h) for p in planes) == 1
    covered = planes[0].inliers | planes[1].inliers
    assert not (covered & leaves).any() and covered[~leaves].mean() > 0.95
    rms, missing = local_roughness(q, 3)
    assert np.median(rms[leaves]) > 1.0 and np.median(rms[~leaves & (v < 75) & (np.abs(u - 60) > 20)]) < 1e-3


def test_segment_plants_checks_its_inputs():
    img = np.zeros((40, 50, 3), np.uint8)
    with pytest.raises(ImageError, match="exactly one depth cue"):
        segment_plants(img)
    with pytest.raises(ImageError, match="registered to the image"):
        segment_plants(img, disparity=np.zeros((40, 49)))
    with pytest.raises(ImageError, match="exactly one"):
        segment_plants(img, disparity=np.zeros((40, 50)), depth=np.ones((40, 50)))
    assert PLANT_SEGMENTER.replace(scale=1.0).scale == 1.0


def test_inverse_depth_of_a_cloud_uses_its_camera(paper_rig):
    from canopy_stereo.sim import CLEAN, render_scene, rig_at_resolution

    sim = render_scene("pots_side_by_side", rig_at_resolution(paper_rig, 0.25), effects=CLEAN, supersample=1)
    q_given = inverse_depth(points=sim.xyz_left, camera=sim.rig.P_left)
    q_estimated = inverse_depth(points=sim.xyz_left)
    ok = np.isfinite(q_given)
    assert np.allclose(q_given[ok], q_estimated[ok], rtol=1e-3)
    assert np.nanmedian(q_given) == pytest.approx(50.0)


def test_plant_sized_regions_apart_stay_apart_and_fragments_join_or_go():
    m = np.zeros((100, 300), bool)
    m[20:60, 20:60] = True      # a seedling
    m[20:60, 70:110] = True     # another, 10 px away at the same depth: not joined
    m[62:66, 20:30] = True      # a fragment of the first (40 px, 2 px below it): joins it
    m[80:84, 250:256] = True    # a stray fragment far from all: not a plant
    q = np.full(m.shape, 30.0)
    inst, plants = plant_instances(m, q)
    assert len(plants) == 2 and inst[64, 25] == 1 and inst[30, 80] == 2 and inst[82, 252] == 0
    # min_plant weighs pixels by their squared depth: a region 3 x farther is 9 x larger
    q[20:60, 70:110] = 10.0
    assert [p["bbox"][0] for p in plant_instances(m, q)[1]] == [20, 70]  # 1/9 of it: still a plant
    assert [p["bbox"][0] for p in plant_instances(m, q, min_plant=0.5)[1]] == [70]
    _, plants = plant_instances(m, q, min_plant=0.0)
    assert len(plants) == 3  # every region a plant; the piece 2 px below the first still joins it
    with pytest.raises(Exception, match="min_plant"):
        plant_instances(m, q, min_plant=2.0)


def test_touching_plants_are_split_by_the_containers_they_grow_from():
    from canopy_stereo.segmentation.roots import container_bands, split_by_roots

    h, w = 120, 200
    solids = np.zeros((h, w), bool)
    solids[90:120, 20:80] = True     # left pot
    solids[90:120, 120:180] = True   # right pot
    bands = np.zeros((h, w), bool)
    bands[80:90, 20:80] = bands[80:90, 120:180] = True
    roots = container_bands(solids, bands)
    assert roots[85, 50] == 1 and roots[85, 150] == 2 and roots[50, 100] == 0
    # two plants whose leaves touch at column 100; the right one 20 % farther; a branch of the
    # left plant (same depth as it) reaches over the right one's foliage
    region = np.zeros((h, w), bool)
    region[10:90, 30:170] = True
    q = np.where(np.arange(w)[None, :] < 100, 50.0, 40.0) * np.ones((h, 1))
    q[10:20, 100:130] = 50.0
    pieces = split_by_roots(region, q, roots)
    assert len(pieces) == 2 and sum(p.sum() for p in pieces) == region.sum()
    left, right = sorted(pieces, key=lambda p: np.nonzero(p)[1].mean())
    assert left[50, 60] and right[50, 140] and left[15, 120]
    inst, plants = plant_instances(region, q, roots=roots)
    assert len(plants) == 2 and inst[15, 120] == 1 and inst[50, 140] == 2
    # standing in one container's band: left whole
    assert split_by_roots(region & (np.arange(w)[None, :] < 110), q, roots) is None
