"""Multi-view fusion on the synthetic croton (turntable): registration against true poses,
coverage of the true leaf surface, views that do not overlap."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.fusion import (
    RegistrationError,
    RegistrationSettings,
    evaluate_model,
    fuse_views,
    invert_transform,
    register_pair,
    transform_error,
    transform_points,
    view_from_reconstruction,
)
from canopy_stereo.pipeline.reconstruct import reconstruct_pair
from canopy_stereo.sim.multiview import (
    downscaled_rig,
    render_views,
    sample_leaf_surfaces,
    sequence_poses,
    write_views,
)

N_VIEWS = 8
RENDERED = (0, 1, 2, 4, 6)   # of the 8-view turntable: neighbours 45 deg apart, and a 90-deg ring


@pytest.fixture(scope="module")
def turntable():
    """Five views of an 8-view turntable sequence of the croton, full resolution (640x480),
    reconstructed with SGBM inside the true plant mask."""
    seq = render_views("croton", None, n_views=N_VIEWS, mode="turntable", seed=0, indices=RENDERED)
    views = {}
    for v in seq.views:
        rec = reconstruct_pair(v.sim.left, v.sim.right, seq.rig, mask=v.mask)
        views[v.index] = (view_from_reconstruction(v.name, rec, seq.rig, v.sim.left), v)
    truth, _ = sample_leaf_surfaces(seq.scene, spacing=1.5)
    return seq, views, truth


def test_sequence_poses_turn_about_the_plant_axis(paper_rig):
    centre, axis = np.array([20.0, -60.0, 700.0]), np.array([0.0, -1.0, 0.0])
    tt = sequence_poses(8, "turntable", centre, axis, paper_rig)
    assert np.allclose(tt[0], np.eye(4))
    for T in tt:
        assert np.allclose(transform_points(T, centre), centre)      # the axis stays put
    step = invert_transform(tt[0]) @ tt[1]
    assert np.isclose(np.degrees(np.arccos((np.trace(step[:3, :3]) - 1) / 2)), 45.0)
    orbit = sequence_poses(4, "orbit", centre, axis, paper_rig, elevation_deg=20.0)
    # the orbiting rig keeps its distance to the centre and rises above the turntable's rig
    from canopy_stereo.geometry.camera import camera_centre

    c0 = camera_centre(paper_rig.P_left)
    dists = [np.linalg.norm(transform_points(T, c0) - centre) for T in orbit]
    assert np.allclose(dists, np.linalg.norm(c0 - centre))
    assert all((transform_points(T, c0) - c0) @ axis > 50.0 for T in orbit)


@pytest.mark.slow
def test_views_render_the_plant_turned(turntable):
    seq, views, _ = turntable
    sim0, sim2 = views[0][1], views[2][1]
    # a leaf point seen in view 0 is where view 2's pose puts it: check with the true xyz
    w0, w2 = sim0.xyz_world(), sim2.xyz_world()
    pts0 = w0[sim0.sim.leaf_ids_left > 0]
    pts2 = w2[sim2.sim.leaf_ids_left > 0]
    from scipy.spatial import cKDTree

    truth, _ = sample_leaf_surfaces(seq.scene, spacing=1.0)
    d0, _ = cKDTree(truth).query(pts0)
    d2, _ = cKDTree(truth).query(pts2)
    assert np.median(d0) < 0.6 and np.median(d2) < 0.6      # both on the world-frame leaves
    assert sim0.mask.dtype == np.uint8 and 0 < (sim0.mask > 0).mean() < 0.6


@pytest.mark.slow
def test_registration_recovers_known_transform_between_two_views(turntable):
    """Neighbouring turntable views 45 degrees apart, poses unknown: features lifted to 3-D,
    then ICP; compared with the true relative pose at the plant."""
    seq, views, _ = turntable
    a, b = views[0][0], views[1][0]
    pr = register_pair(a, b, settings=RegistrationSettings(voxel=3.0))
    T_true = invert_transform(views[0][1].pose) @ views[1][1].pose
    dt, dr = transform_error(pr.transform, T_true, centre=b.points.mean(axis=0))
    assert pr.initial == "features" and pr.features.inliers >= 20
    assert dt < 2.0 and dr < 1.0           # mm at the plant, degrees (45 degree step)
    assert pr.icp.overlap > 0.6


@pytest.mark.slow
def test_views_without_overlap_fail_clearly(turntable):
    """Opposite sides of the plant (180 degrees): the pot looks the same from every angle and
    lures the matcher into "no motion", but the check refuses the result."""
    _, views, _ = turntable
    with pytest.raises(RegistrationError, match="'view_00' and 'view_04' do not overlap"):
        register_pair(views[0][0], views[4][0], settings=RegistrationSettings(voxel=3.0))


@pytest.mark.slow
def test_fused_coverage_beats_single_views(turntable):
    """Four views 90 degrees apart with their true poses: the fused model covers far more
    of the true leaf surface than any single view, and stays as accurate."""
    seq, views, truth = turntable
    ring = [views[i][0] for i in (0, 2, 4, 6)]
    poses = [views[i][1].pose for i in (0, 2, 4, 6)]
    fused = fuse_views(ring, poses, voxel=2.0)
    radius = 3.0
    single = [evaluate_model(v.world_points(T), truth, radius, max_distance=10.0) for v, T in zip(ring, poses)]
    model = evaluate_model(fused.points, truth, radius, max_distance=10.0)
    best = max(s.coverage for s in single)
    assert model.coverage > best + 0.2 and model.coverage > 0.85
    assert model.median_error < 1.2 * min(s.median_error for s in single) + 0.5
    assert fused.view_count.max() >= 3
    # voxels seen through by another view were removed, each with its points: the points kept
    # are the input less at least one per removed voxel
    lost = fused.stats["input_points"] - fused.point_count.sum()
    assert 0 < fused.removed_free_space <= lost
    kept = fuse_views(ring, poses, voxel=2.0, free_space=False)
    assert kept.removed_free_space == 0 and kept.point_count.sum() == kept.stats["input_points"]
    assert fused.colors is not None and len(fused.colors) == len(fused)


def test_write_views_layout(tmp_path, paper_rig):
    from canopy_stereo.fusion import read_poses

    rig = downscaled_rig(paper_rig, 4)
    seq = render_views("croton", rig, n_views=4, mode="orbit", seed=1, supersample=1, indices=(0, 1))
    out = write_views(seq, tmp_path / "views")
    for name in ("view_00", "view_01"):
        for f in ("left.png", "right.png", "mask.png", "rig.yaml"):
            assert (out / name / f).is_file()
    ps = read_poses(out / "poses_true.yaml")
    assert ps.unit == "mm" and np.allclose(ps["view_01"], seq.views[1].pose, atol=1e-8)
    assert (out / "truth.json").is_file()
