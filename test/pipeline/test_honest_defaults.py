"""Honest defaults (issue 23, item 5): the disparity range from a working distance in metres,
a warning when pixels pile up at its ends, a swapped pair refused.

The scene: a textured board (the simulator's ``backdrop`` material) at half the old nearest
depth (8 baselines -> 4 baselines, about 120 mm on the paper's rig) in front of a backdrop,
rendered through config/paper_rig.yaml with exact truth.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def near_board():
    from canopy_stereo.geometry.camera import decompose_projection
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.sim.primitives import Material, Rectangle
    from canopy_stereo.sim.render import render_pair
    from canopy_stereo.sim.scene import Scene, place_in_front_of

    rig = load_rig(REPO / "config/paper_rig.yaml")
    baseline_mm = float(np.linalg.norm(decompose_projection(rig.P_left).C - decompose_projection(rig.P_right).C)
                        * rig.metres_per_unit * 1000.0)
    depth = 0.5 * 8.0 * baseline_mm  # half the old default's nearest depth
    facing = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    backdrop = Rectangle([0.0, 0.0, 600.0], facing, np.inf, np.inf, Material("backdrop", 3, (3.0,)))
    board = Rectangle([0.0, 0.0, depth], facing, 0.25 * depth, 0.2 * depth, Material("backdrop", 7, (1.0,)))
    scene = place_in_front_of(Scene(name="near_board", seed=0, primitives=(backdrop, board), background=backdrop,
                                    light=np.array([0.3, -0.5, -0.8]) / np.linalg.norm([0.3, -0.5, -0.8])), rig)
    sim = render_pair(scene, rig)
    return rig, sim, depth


@pytest.mark.slow
def test_a_board_at_half_the_old_nearest_depth_is_reconstructed_with_a_working_distance(near_board):
    from canopy_stereo.geometry.camera import camera_centre
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rig, sim, depth = near_board
    c = camera_centre(rig.P_left)
    dist_true = np.linalg.norm(sim.xyz_left - c, axis=-1)
    board = dist_true < 1.5 * depth
    assert board.mean() > 0.2  # the board fills a good part of the view

    def recall(rec):
        got = np.linalg.norm(rec.organized - c, axis=-1)
        return float((board & np.isfinite(got) & (np.abs(got - dist_true) < 0.03 * dist_true)).sum() / board.sum())

    old = reconstruct_pair(sim.left, sim.right, rig)  # the old default: depths beyond 8 baselines
    assert recall(old) < 0.2
    assert old.warnings and "largest disparity searched" in old.warnings[0] and "--near" in old.warnings[0]
    near_m = 0.8 * depth / 1000.0
    new = reconstruct_pair(sim.left, sim.right, rig, near_m=near_m, far_m=1.0)
    assert recall(new) > 0.8 and not new.warnings
    # the same from the rig file's keys
    again = reconstruct_pair(sim.left, sim.right, rig.with_extra(near_m=near_m, far_m=1.0))
    assert again.disp_range == new.disp_range
    assert np.array_equal(np.isfinite(again.organized), np.isfinite(new.organized))


@pytest.mark.slow
def test_a_swapped_pair_is_refused(near_board, tmp_path, cli):
    from canopy_stereo.io.images import write_image
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rig, sim, depth = near_board
    with pytest.raises(CanopyStereoError, match="swapped"):
        reconstruct_pair(sim.right, sim.left, rig, near_m=0.8 * depth / 1000.0, far_m=1.0)
    left, right = write_image(tmp_path / "l.png", sim.left), write_image(tmp_path / "r.png", sim.right)
    code, out, err = cli("reconstruct", right, left, "--rig", REPO / "config/paper_rig.yaml", "--near",
                         0.8 * depth / 1000.0, "--far", 1.0, "-o", tmp_path / "c.ply")
    errors = [ln for ln in err.splitlines() if "error" in ln]  # (beside the kernels' warm-up note)
    assert code == 2 and len(errors) == 1 and "left and right images are swapped" in errors[0]
    assert "Traceback" not in err
    assert not (tmp_path / "c.ply").exists()


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["croton", "plants"])
def test_bundled_pairs_swapped_are_refused(scene):
    """The bundled bags' first pairs, exchanged: refused by their rigs (verging croton cameras:
    the matches leave their rows; parallel Middlebury cameras: they leave the working range)."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.batch.frames import image_to_bgr, raw_stereo_pairs
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair
    from canopy_stereo.ros.bundled import LEFT_TOPIC, RIGHT_TOPIC, bundled_bag, bundled_rig

    _, left, right = next(iter(raw_stereo_pairs(BagReader(bundled_bag(scene)), LEFT_TOPIC,
                                                 right_topic=RIGHT_TOPIC, slop_s=0.015)))
    left, right, rig = image_to_bgr(left), image_to_bgr(right), load_rig(bundled_rig(scene))
    with pytest.raises(CanopyStereoError, match="swapped"):
        reconstruct_pair(right, left, rig)
    assert not reconstruct_pair(left, right, rig).warnings
