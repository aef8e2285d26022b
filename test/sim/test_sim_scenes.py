"""Named scenes: the croton's marked leaves, occlusions, distances, seeds and breeze frames."""
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import point_depth
from canopy_stereo.sim import (
    CLEAN,
    CROTON_MARKED,
    SCENES,
    build_scene,
    render_pair,
    render_scene,
    rig_at_resolution,
    scene_for_rig,
)


@pytest.fixture(scope="module")
def croton(paper_rig):
    return render_scene("croton", paper_rig, effects=CLEAN, supersample=1)


def test_croton_marked_leaves_have_the_papers_sizes():
    for seed in (0, 1, 7):
        scene = build_scene("croton", seed)
        assert scene.marked_leaf_ids == [1, 2]
        for leaf_id, (width, length) in CROTON_MARKED.items():
            lf = scene.leaf(leaf_id)
            assert lf.length == pytest.approx(length, abs=1e-9)
            assert lf.width == pytest.approx(width, abs=1e-9)
            assert lf.name == f"leaf{leaf_id}"
        assert len(scene.leaves) >= 10


def test_croton_is_500_to_800_mm_away_with_its_marked_leaves_in_full_view(croton, paper_rig):
    sim = croton
    leaf = sim.leaf_ids_left > 0
    depth = point_depth(paper_rig.P_left, sim.xyz_left[leaf])
    assert 500 < np.percentile(depth, 2) and np.percentile(depth, 98) < 800
    isolated_scenes = {i: sim.scene.only_leaves([i]) for i in sim.truth["marked_leaf_ids"]}
    for leaf_id, scene in isolated_scenes.items():
        alone = render_pair(scene, paper_rig, supersample=1, effects=CLEAN)
        for side in ("left", "right"):
            full = getattr(sim, f"leaf_ids_{side}") == leaf_id
            solo = getattr(alone, f"leaf_ids_{side}") == leaf_id
            assert full.sum() > 5000
            # nothing in the plant hides any part of a marked leaf, in either view
            assert np.array_equal(full, solo), (leaf_id, side)
            # and the leaf does not touch the image border
            assert not (full[0].any() or full[-1].any() or full[:, 0].any() or full[:, -1].any())
    truth = {lf["id"]: lf for lf in sim.truth["leaves"]}
    assert truth[1]["pixels_left"] == int((sim.leaf_ids_left == 1).sum())
    assert truth[1]["length"] == pytest.approx(160.0) and truth[2]["width"] == pytest.approx(86.0)


@pytest.mark.slow
def test_citrus_branch_has_many_small_leaves_that_occlude_each_other(paper_rig):
    rig = rig_at_resolution(paper_rig, 0.5)
    sim = render_scene("citrus_branch", rig, effects=CLEAN, supersample=1)
    leaves = sim.truth["leaves"]
    assert len(leaves) >= 40
    lengths = np.array([lf["length"] for lf in leaves])
    assert lengths.min() >= 30 - 1e-9 and lengths.max() <= 80 + 1e-9
    visible = [lf for lf in leaves if lf["pixels_left"] > 0]
    assert len(visible) >= 30
    # occlusion: some leaves show fewer pixels than when rendered alone
    occluded = 0
    for lf in sorted(visible, key=lambda x: -x["pixels_left"])[:15]:
        alone = render_pair(sim.scene.only_leaves([lf["id"]]), rig, supersample=1, effects=CLEAN)
        n_alone = int((alone.leaf_ids_left == lf["id"]).sum())
        assert n_alone >= lf["pixels_left"]
        occluded += n_alone > lf["pixels_left"] + 10
    assert occluded >= 3
    assert sim.scene.background_distance == pytest.approx(1500.0)


def test_seedling_tray_is_a_top_view_of_small_plants(paper_rig):
    scene = scene_for_rig("seedling_tray", paper_rig)
    leaves = scene.leaves
    assert len(leaves) >= 60
    assert max(lf.length for lf in leaves) <= 26 + 1e-9
    view = scene.anchor_axes[2]
    # leaves face the cameras (upper sides towards them) and rise above the soil
    facing = np.array([-(lf.axes[2] @ view) for lf in leaves])
    assert np.median(facing) > 0.8
    heights = np.array([scene.background_distance - (lf.base - scene.anchor_origin) @ view
                        for lf in leaves])
    assert np.all((heights > 5) & (heights < 40))
    assert scene.background_distance == pytest.approx(420.0)


def test_breeze_frames_move_leaves_gently_and_keep_their_sizes():
    rest = build_scene("croton", 0)
    assert rest.at_frame(0).posed is rest.posed
    prev = rest
    moved = []
    for frame in range(1, 5):
        scene = rest.at_frame(frame)
        assert scene.truth()["frame"] == frame
        for a, b in zip(prev.leaves, scene.leaves):
            step = np.linalg.norm(a.tip - b.tip)
            assert step < 4.0  # mm per frame: a gentle breeze
            assert b.length == pytest.approx(a.length) and b.width == pytest.approx(a.width)
            assert np.allclose(a.base, b.base)
            moved.append(step)
        prev = scene
    assert np.mean(moved) > 0.2
    # the rest pose is frame 0 of every sequence
    assert np.allclose(rest.at_frame(0).leaf(1).tip, rest.leaf(1).tip)


def test_breeze_frames_render_with_their_own_truth(paper_rig):
    rig = rig_at_resolution(paper_rig, 0.25)
    a = render_scene("croton", rig, frame=0, effects=CLEAN, supersample=1)
    b = render_scene("croton", rig, frame=3, effects=CLEAN, supersample=1)
    assert b.truth["frame"] == 3
    tip_a = np.array(a.truth["leaves"][0]["pose"]["tip"])
    tip_b = np.array(b.truth["leaves"][0]["pose"]["tip"])
    assert 0 < np.linalg.norm(tip_a - tip_b) < 10
    changed = np.mean(a.leaf_ids_left != b.leaf_ids_left)
    assert 0 < changed < 0.05


def test_scene_names_and_seed_are_checked():
    assert set(SCENES) == {"croton", "citrus_branch", "seedling_tray", "potted_distractors",
                           "pots_side_by_side"}
    with pytest.raises(CanopyStereoError, match="unknown scene"):
        build_scene("tomato")
    with pytest.raises(CanopyStereoError, match="seed"):
        build_scene("croton", -1)
    with pytest.raises(CanopyStereoError, match="frame"):
        build_scene("croton").at_frame(-2)
