"""Fusion core on synthetic clouds: transforms, pose files, ICP, pose graph, voxel fusion,
free space, coverage (no rendering, no stereo)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion import (
    DepthView,
    IncrementalFusion,
    RegistrationError,
    RegistrationSettings,
    UnitMismatchError,
    View,
    common_unit,
    evaluate_model,
    fuse_point_sets,
    icp_point_to_plane,
    read_poses,
    register_pair,
    register_views,
    rigid_fit,
    transform_error,
    transform_points,
    turntable_pose,
    write_poses,
)
from canopy_stereo.fusion.posegraph import PoseGraphEdge, edge_residuals, optimize_pose_graph
from canopy_stereo.fusion.voxel import pack_keys, unpack_keys, voxel_downsample
from canopy_stereo.geometry.transforms import (
    check_transform,
    exp_se3,
    invert_transform,
    log_se3,
    make_transform,
    rotation_about_axis,
    rotation_from_rotvec,
    rotvec_from_rotation,
)


def leafy_cloud(rng, n_patches=14, spread=90.0, radius=30.0, spacing=1.5):
    """A canopy-like cloud (mm): curved discs at random positions and tilts."""
    pts = []
    for _ in range(n_patches):
        c = rng.uniform(-spread, spread, 3)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        a = np.cross(n, [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        g = np.arange(-radius, radius, spacing)
        u, v = [x.ravel() for x in np.meshgrid(g, g)]
        keep = u * u + v * v < radius * radius
        u, v = u[keep], v[keep]
        h = 0.01 * (u * u + v * v)
        pts.append(c + u[:, None] * a + v[:, None] * b + h[:, None] * n)
    return np.concatenate(pts)


# ----------------------------------------------------------------------------- transforms
def test_rotvec_round_trip_and_exp_log(rng):
    for angle in (1e-9, 0.3, 2.0, np.pi - 1e-6):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = rotation_from_rotvec(axis * angle)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(rotation_from_rotvec(rotvec_from_rotation(R)), R, atol=1e-8)
    xi = np.array([0.1, -0.2, 0.05, 3.0, -1.0, 2.0])
    assert np.allclose(log_se3(exp_se3(xi)), xi)


def test_rigid_fit_recovers_transform(rng):
    src = rng.uniform(-50, 50, (40, 3))
    T = make_transform(rotation_about_axis([1, 2, 3], 0.7), [10, -5, 200])
    est = rigid_fit(src, transform_points(T, src))
    assert np.allclose(est, T, atol=1e-9)
    assert np.allclose(invert_transform(T) @ T, np.eye(4), atol=1e-12)


def test_check_transform_rejects_non_rigid():
    with pytest.raises(CanopyStereoError, match="not a rotation"):
        check_transform(np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(CanopyStereoError, match="4x4"):
        check_transform([1, 2, 3])
    with pytest.raises(CanopyStereoError, match="last row"):
        check_transform(np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]))


# ----------------------------------------------------------------------------- pose files
def test_poses_file_round_trip_and_turntable(tmp_path):
    T = make_transform(rotation_about_axis([0, 1, 0], 0.4), [1.5, -2.0, 30.0])
    path = write_poses(tmp_path / "poses.yaml", {"a": np.eye(4), "b": T}, "mm")
    ps = read_poses(path)
    assert ps.unit == "mm" and set(ps.poses) == {"a", "b"}
    assert np.allclose(ps["b"], T, atol=1e-9)
    (tmp_path / "tt.yaml").write_text(
        "unit: mm\nturntable:\n  axis_point: [0, 0, 700]\n  axis_direction: [0, -1, 0]\n"
        "  angles_deg: {v0: 0, v1: 90}\n")
    tt = read_poses(tmp_path / "tt.yaml")
    assert np.allclose(tt["v0"], np.eye(4))
    # the axis is fixed by the pose; a point in front of the rig moves a quarter turn round it
    assert np.allclose(transform_points(tt["v1"], [0, 0, 700]), [0, 0, 700])
    assert np.allclose(tt["v1"], turntable_pose(90, [0, 0, 700], [0, -1, 0]))
    assert np.isclose(np.linalg.norm(transform_points(tt["v1"], [0, 0, 600]) - [0, 0, 700]), 100)


@pytest.mark.parametrize("text, message", [
    ("poses: {a: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}\n", "no 'unit'"),
    ("unit: furlong\nposes: {a: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]}\n", "unknown world_unit"),
    ("unit: mm\nposes: {a: [1, 2, 3]}\n", "pose of 'a'"),
    ("unit: mm\n", "holds no pose"),
    ("- just a list\n", "must be a mapping"),
])
def test_bad_pose_files_name_the_problem(tmp_path, text, message):
    path = tmp_path / "poses.yaml"
    path.write_text(text)
    with pytest.raises(CanopyStereoError, match=message):
        read_poses(path)


# ----------------------------------------------------------------------------- voxels
def test_voxel_keys_round_trip_and_downsample_means(rng):
    ijk = rng.integers(-5000, 5000, (100, 3))
    assert np.array_equal(unpack_keys(pack_keys(ijk)), ijk)
    pts = np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.9], [1.5, 0.2, 0.2], [-0.5, 0.0, 0.0]])
    cols = np.array([[0, 0, 0], [200, 100, 50], [10, 10, 10], [255, 255, 255]], np.uint8)
    means, mc, counts = voxel_downsample(pts, 1.0, colors=cols)
    order = np.argsort(means[:, 0])
    assert np.allclose(means[order], [[-0.5, 0, 0], [0.5, 0.5, 0.5], [1.5, 0.2, 0.2]])
    assert counts[order].tolist() == [1, 2, 1]
    assert mc[order][1].tolist() == [100, 50, 25]


# ----------------------------------------------------------------------------- ICP
def test_icp_recovers_known_transform_with_partial_overlap(rng):
    cloud = leafy_cloud(rng)
    T = make_transform(rotation_about_axis([0.2, 1.0, 0.1], np.radians(8)), [6.0, -3.0, 4.0])
    src = cloud[cloud[:, 0] < 40] + rng.normal(0, 0.3, (int((cloud[:, 0] < 40).sum()), 3))
    tgt_pts = cloud[cloud[:, 0] > -40]
    tgt = transform_points(T, tgt_pts) + rng.normal(0, 0.3, tgt_pts.shape)
    wide = icp_point_to_plane(src, tgt, T_init=np.eye(4), max_distance=30.0)
    fine = icp_point_to_plane(src, tgt, T_init=wide.transform, max_distance=3.0)
    dt, dr = transform_error(fine.transform, T, centre=src.mean(axis=0))
    assert dt < 0.1 and dr < 0.05
    assert fine.converged
    assert 0.4 < fine.overlap < 0.95          # only part of the source has a partner
    assert fine.rmse < 0.6                    # about the noise level
    assert fine.information.shape == (6, 6) and np.all(np.linalg.eigvalsh(fine.information) > 0)


def test_icp_without_overlap_fails_clearly(rng):
    cloud = leafy_cloud(rng, n_patches=4)
    with pytest.raises(CanopyStereoError, match="do not overlap"):
        icp_point_to_plane(cloud, cloud + [1000.0, 0, 0], max_distance=10.0)


def _cloud_view(name, points, unit="mm", pose=None):
    return View(name=name, points=points, colors=None, unit=unit, pose=pose)


@pytest.mark.slow
def test_register_pair_of_clouds_and_no_overlap_error(rng):
    cloud = leafy_cloud(rng)
    T = make_transform(rotation_about_axis([0, 1, 0], np.radians(3)), [2.0, 1.0, -1.5])
    a = _cloud_view("a", cloud[cloud[:, 1] < 50])
    b = _cloud_view("b", transform_points(invert_transform(T), cloud[cloud[:, 1] > -50]))
    pr = register_pair(a, b, settings=RegistrationSettings(voxel=2.0))   # no images: ICP from identity
    assert pr.initial == "identity"
    dt, dr = transform_error(pr.transform, T, centre=b.points.mean(axis=0))
    assert dt < 0.05 and dr < 0.02
    far = _cloud_view("far", cloud + [0.0, 0.0, 2000.0])
    with pytest.raises(RegistrationError, match="'a' and 'far'"):
        register_pair(a, far, settings=RegistrationSettings(voxel=2.0))
    other = _cloud_view("other", leafy_cloud(np.random.default_rng(99)))
    with pytest.raises(RegistrationError, match="do not overlap|register poorly|could not be registered"):
        register_pair(a, other, settings=RegistrationSettings(voxel=2.0))


def test_mismatched_units_are_an_error(rng):
    cloud = leafy_cloud(rng, n_patches=3)
    a, b = _cloud_view("a", cloud, "mm"), _cloud_view("b", cloud / 1000.0, "m")
    with pytest.raises(UnitMismatchError, match="a: mm, b: m"):
        common_unit([a, b])
    with pytest.raises(UnitMismatchError):
        register_pair(a, b)
    with pytest.raises(UnitMismatchError, match="pose file is in m"):
        common_unit([a], poses_unit="m")


# ----------------------------------------------------------------------------- pose graph
def test_pose_graph_spreads_loop_error():
    """Each registration of a turntable loop over-turns by 0.3 degrees (plus noise): the
    chain drifts by 2.1 degrees, the closed loop cancels the common bias."""
    n = 8
    step = turntable_pose(360.0 / n, [0, 0, 700], [0, -1, 0])
    truth = [np.linalg.matrix_power(step, k) for k in range(n)]
    rng = np.random.default_rng(3)
    bias = turntable_pose(0.3, [0, 0, 700], [0, -1, 0])
    edges, chain = [], [np.eye(4)]
    for k in range(n):
        i, j = k, (k + 1) % n
        noise = bias @ exp_se3(np.concatenate([rng.normal(0, 2e-4, 3), rng.normal(0, 0.05, 3)]))
        meas = noise @ invert_transform(truth[i]) @ truth[j]
        edges.append(PoseGraphEdge(i, j, meas, np.diag([1e5, 1e5, 1e5, 1.0, 1.0, 1.0])))
        if j:
            chain.append(chain[-1] @ meas)
    optimised = optimize_pose_graph(chain, edges, fixed=0)
    def err(poses):   # worst rotation error, degrees
        return max(transform_error(P, T, centre=[150, 0, 700])[1] for P, T in zip(poses, truth))

    assert err(chain) > 2.0 and err(optimised) < 0.15 * err(chain)
    before = edge_residuals(chain, edges)[-1][0]
    after = max(r[0] for r in edge_residuals(optimised, edges))
    assert after < 0.5 * before                 # the closing error is shared by all edges
    assert np.allclose(optimised[0], np.eye(4))


@pytest.mark.slow
def test_register_views_closes_loop_of_clouds(rng):
    """Four cloud views round a ring of patches, registered from identity (small steps)."""
    cloud = leafy_cloud(rng, n_patches=20, spread=70.0)
    n = 4
    step = make_transform(rotation_about_axis([0, 1, 0], np.radians(4)), [1.0, 0.0, 0.5])
    truth = [np.linalg.matrix_power(step, k) for k in range(n)]
    views = [_cloud_view(f"v{k}", transform_points(invert_transform(truth[k]), cloud)
                         + rng.normal(0, 0.2, cloud.shape)) for k in range(n)]
    res = register_views(views, RegistrationSettings(voxel=2.0), loop="auto")
    assert res.loop_closed and len(res.pairs) == n
    for P, T in zip(res.poses, truth):
        dt, dr = transform_error(P, T, centre=cloud.mean(axis=0))
        assert dt < 0.1 and dr < 0.05


def test_register_views_refuses_a_loop_that_does_not_close(rng, monkeypatch):
    """One pair registered 30 degrees wrong (as when a symmetric pot lures the matcher):
    the closing edge disagrees with the chain and registration fails instead of fusing garbage."""
    from canopy_stereo.fusion import registration as reg_module

    cloud = leafy_cloud(rng, n_patches=20, spread=70.0)
    step = make_transform(rotation_about_axis([0, 1, 0], np.radians(4)), [1.0, 0.0, 0.5])
    views = [_cloud_view(f"v{k}", transform_points(invert_transform(np.linalg.matrix_power(step, k)), cloud))
             for k in range(4)]
    real = reg_module._register

    def corrupted(target, source, s, T_init=None, use_features=True, indices=(0, 1)):
        pr = real(target, source, s, T_init, use_features, indices)
        if indices == (1, 2):
            pr.transform = make_transform(rotation_about_axis([0, 1, 0], np.radians(30))) @ pr.transform
        return pr

    monkeypatch.setattr(reg_module, "_register", corrupted)
    with pytest.raises(RegistrationError, match="the loop does not close"):
        register_views(views, RegistrationSettings(voxel=2.0), loop="auto")


# ----------------------------------------------------------------------------- fusion
def _plane_depth_view(P, z_plane, size=(200, 150)):
    w, h = size
    return DepthView(P=P, depth=np.full((h, w), z_plane, np.float32))


def test_fusion_averages_counts_views_and_removes_seen_through_outlier():
    K = np.array([[200.0, 0, 99.5], [0, 200.0, 74.5], [0, 0, 1]])
    P = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    g = np.arange(-40.0, 40.0, 1.0)
    u, v = [x.ravel() for x in np.meshgrid(g, g)]
    plane = np.stack([u, v, np.full(u.shape, 501.0)], axis=1)   # mid-voxel
    a = plane + [0, 0, 0.3]
    b = plane - [0, 0, 0.3]
    floater = np.array([[0.0, 0.0, 300.0]])         # seen by view a only, in front of the plane
    col = lambda n, c: np.tile(np.array(c, np.uint8), (n, 1))  # noqa: E731
    sets = [(np.vstack([a, floater]), col(len(a) + 1, [200, 0, 0])), (b, col(len(b), [0, 0, 100]))]
    dvs = [_plane_depth_view(P, 500.0), _plane_depth_view(P, 500.0)]
    kept = fuse_point_sets(sets, 2.0, "mm", depth_views=dvs, free_space=False)
    fused = fuse_point_sets(sets, 2.0, "mm", depth_views=dvs, free_space=True)
    assert len(kept) == len(fused) + 1 and fused.removed_free_space == 1
    assert not np.any(np.linalg.norm(fused.points - floater, axis=1) < 5)
    assert np.all(fused.view_count == 2)                  # both views saw all of the plane
    assert np.allclose(fused.points[:, 2], 501.0, atol=1e-6)  # one layer: the views are averaged
    assert len(fused) == 40 * 40                          # one point per 2 mm voxel of the plane
    assert np.all(fused.colors[:, 0] == 100) and np.all(fused.colors[:, 2] == 50)  # mean colour
    assert fused.point_count.sum() == len(a) + len(b)
    # a lone point behind the plane is occluded, not seen through: it stays
    behind = [(np.array([[0.0, 0.0, 700.0]]), None), (b, None)]
    kept_behind = fuse_point_sets(behind, 2.0, "mm", depth_views=dvs, free_space=True)
    assert kept_behind.removed_free_space == 0
    assert fuse_point_sets(sets, 2.0, "mm", min_views=2).view_count.min() == 2


def test_depth_view_from_points_and_coverage():
    K = np.array([[100.0, 0, 49.5], [0, 100.0, 49.5], [0, 0, 1]])
    P = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    g = np.arange(-20.0, 20.0, 0.5)
    u, v = [x.ravel() for x in np.meshgrid(g, g)]
    plane = np.stack([u, v, np.full(u.shape, 200.0)], axis=1)
    dv = DepthView.from_points(P, plane, (100, 100), np.eye(4), erode_px=1)
    assert np.isclose(dv.depth[50, 50], 200.0)
    seen = dv.seen_through(np.array([[0, 0, 100.0], [0, 0, 199.0], [0, 0, 300.0]]), 2.0, 0.0)
    assert seen.tolist() == [True, False, False]
    half = plane[plane[:, 0] < 0]
    assert abs(evaluate_model(half, plane, 0.3).coverage - 0.5) < 0.02
    rep = evaluate_model(half + [0, 0, 1.0], plane, 1.5)
    assert np.isclose(rep.median_error, 1.0) and rep.coverage > 0.45


@pytest.mark.slow
def test_incremental_fusion_registers_stream_and_resets(rng):
    cloud = leafy_cloud(rng, n_patches=16, spread=70.0)
    step = make_transform(rotation_about_axis([0, 1, 0], np.radians(3)), [1.0, 0.0, 0.0])
    inc = IncrementalFusion(voxel=2.0, unit="mm")
    T = np.eye(4)
    for k in range(3):
        res = inc.add(transform_points(invert_transform(T), cloud))
        assert res.registered == (k > 0)
        assert transform_error(res.pose, T, centre=cloud.mean(axis=0))[0] < 0.1
        T = T @ step
    fused = inc.fused()
    assert fused.view_count.max() == 3 and inc.view_count == 3
    with pytest.raises(RegistrationError):
        inc.add(cloud + [5000.0, 0, 0])
    inc.reset()
    assert inc.view_count == 0
    given = inc.add(cloud, pose=step)
    assert not given.registered and np.allclose(given.pose, step)
