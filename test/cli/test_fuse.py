"""``canopy-stereo fuse``: PLY and stereo-pair views, poses files, residual report, bad input."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.fusion import read_poses, transform_error, transform_points, write_pose, write_poses
from canopy_stereo.geometry.transforms import invert_transform, make_transform, rotation_about_axis
from canopy_stereo.io.ply import read_ply, write_ply
from test.support.fusion import patch_points


def patch_cloud(seed=0, n=10):
    """Curved coloured patches (mm) roughly 600 mm in front of a rig."""
    pts = patch_points(seed, n, unit="mm")
    return pts, np.clip(128 + pts[:, :3] % 100, 0, 255).astype(np.uint8)


STEP = make_transform(rotation_about_axis([0, 1, 0], np.radians(3.0)), [2.0, 0.0, 1.0])


def make_cloud_views(root, n=3, unit="mm", with_pose=False):
    """``n`` cloud.ply views of one scene seen from poses STEP^k (rig frame points)."""
    pts, cols = patch_cloud()
    dirs, poses = [], {}
    for k in range(n):
        T = np.linalg.matrix_power(STEP, k)
        d = root / f"v{k}"
        d.mkdir(parents=True)
        scale = 0.001 if unit == "m" else 1.0
        write_ply(d / "cloud.ply", transform_points(invert_transform(T), pts) * scale, colors=cols, unit=unit)
        if with_pose:
            write_pose(d / "pose.yaml", T, unit)
        poses[d.name] = T
        dirs.append(d)
    return dirs, poses


def test_fuse_ply_views_with_poses_file(tmp_path, cli):
    dirs, poses = make_cloud_views(tmp_path)
    write_poses(tmp_path / "poses.yaml", poses, "mm")
    out = tmp_path / "fused.ply"
    code, stdout, stderr = cli("fuse", *dirs, "-o", out, "--poses", tmp_path / "poses.yaml", "--voxel", "2mm")
    assert code == 0, stderr
    assert "poses given; residuals" in stdout and "v0 <- v1: rmse" in stdout
    cloud = read_ply(out)
    # a fused voxel's colour is a mean of the patches' colours, which lie in 128..227
    assert cloud.unit == "mm" and cloud.colors.shape == (len(cloud), 3)
    assert cloud.colors.min() >= 128 and cloud.colors.max() <= 227
    views = cloud.extra["views"]
    assert views.max() == 3 and np.mean(views == 3) > 0.8          # the same scene from 3 poses
    pts, _ = patch_cloud()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts).query(cloud.points)
    assert np.median(d) < 0.75          # in the world frame (truth sampled every 1 mm)
    assert cloud.extra["points"].sum() == 3 * len(pts)


def test_fuse_registers_ply_views_without_poses(tmp_path, cli):
    dirs, poses = make_cloud_views(tmp_path, n=3)
    out = tmp_path / "fused.ply"
    code, stdout, stderr = cli("fuse", *dirs, "-o", out, "--voxel", "0.002m", "--poses-out", tmp_path / "est.yaml")
    assert code == 0, stderr
    assert "registration (world = rig frame of v0)" in stdout
    assert "v0 <- v1: ICP rmse" in stdout and "v1 <- v2: ICP rmse" in stdout
    # clouds without images start ICP from identity: v2 is too far turned from v0 to close the loop
    assert "loop not closed" in stdout
    est = read_poses(tmp_path / "est.yaml")
    centre = patch_cloud()[0].mean(axis=0)
    for name, T in poses.items():
        dt, dr = transform_error(est[name], T, centre=centre)
        assert dt < 0.1 and dr < 0.05


def test_fuse_uses_pose_yaml_in_view_folders(tmp_path, cli):
    dirs, _ = make_cloud_views(tmp_path, n=2, with_pose=True)
    code, stdout, stderr = cli("fuse", *dirs, "-o", tmp_path / "f.ply")
    assert code == 0, stderr
    assert "pose from pose.yaml" in stdout and "poses given" in stdout


def test_fuse_mismatched_units_is_an_error(tmp_path, cli):
    a, _ = make_cloud_views(tmp_path / "a", n=1, unit="mm")
    b, _ = make_cloud_views(tmp_path / "b", n=1, unit="m")
    (b[0].parent / "v0").rename(b[0].parent / "w0")
    code, _, stderr = cli("fuse", a[0], b[0].parent / "w0", "-o", tmp_path / "f.ply")
    assert code == 2
    assert "different units" in stderr and "v0: mm" in stderr and "w0: m" in stderr
    assert "Traceback" not in stderr


def test_fuse_pose_file_in_another_unit_is_an_error(tmp_path, cli):
    dirs, poses = make_cloud_views(tmp_path, n=2)
    write_poses(tmp_path / "poses.yaml", poses, "m")
    code, _, stderr = cli("fuse", *dirs, "-o", tmp_path / "f.ply", "--poses", tmp_path / "poses.yaml")
    assert code == 2 and "is in m but the views are in mm" in stderr


def test_fuse_views_that_do_not_overlap_fail_clearly(tmp_path, cli):
    pts, cols = patch_cloud(seed=0)
    for name, shift in (("near", 0.0), ("far", 3000.0)):
        (tmp_path / name).mkdir()
        write_ply(tmp_path / name / "cloud.ply", pts + [shift, 0, 0], colors=cols, unit="mm")
    out = tmp_path / "f.ply"
    code, _, stderr = cli("fuse", tmp_path / "near", tmp_path / "far", "-o", out)
    assert code == 2
    assert "'near' and 'far'" in stderr and ("do not overlap" in stderr or "could not be registered" in stderr)
    assert not out.exists()                      # no silent garbage


@pytest.mark.parametrize("case, message", [
    ("partial", "have no pose while"),
    ("unknown", "names view(s) ghost"),
    ("empty", "neither a stereo pair"),
    ("voxel", "--voxel: unknown unit"),
])
def test_fuse_bad_input_messages(tmp_path, cli, case, message):
    dirs, poses = make_cloud_views(tmp_path, n=2)
    args = [*dirs, "-o", tmp_path / "f.ply"]
    if case == "partial":
        write_pose(dirs[0] / "pose.yaml", np.eye(4), "mm")
    elif case == "unknown":
        write_poses(tmp_path / "p.yaml", {**poses, "ghost": np.eye(4)}, "mm")
        args += ["--poses", tmp_path / "p.yaml"]
    elif case == "empty":
        (tmp_path / "empty").mkdir()
        args = [tmp_path / "empty", *args]
    elif case == "voxel":
        write_poses(tmp_path / "p.yaml", poses, "mm")
        args += ["--poses", tmp_path / "p.yaml", "--voxel", "2parsecs"]
    code, _, stderr = cli("fuse", *args)
    assert code == 2 and message in stderr, stderr


@pytest.mark.slow
def test_fuse_stereo_pair_views_registered(tmp_path, cli):
    """Two rendered turntable views (stereo pairs + rig files) 45 degrees apart, no poses."""
    from canopy_stereo.sim.multiview import render_views, write_views

    seq = render_views("croton", None, n_views=8, mode="turntable", seed=0, indices=(0, 1), supersample=1)
    root = write_views(seq, tmp_path / "views")
    out = tmp_path / "fused.ply"
    code, stdout, stderr = cli("fuse", root / "view_00", root / "view_01", "-o", out,
                               "--poses-out", tmp_path / "est.yaml")
    assert code == 0, stderr
    assert "view_00 <- view_01: ICP rmse" in stdout and "features" in stdout
    est = read_poses(tmp_path / "est.yaml")["view_01"]
    true = read_poses(root / "poses_true.yaml")["view_01"]
    dt, dr = transform_error(est, true, centre=seq.centre)
    assert dt < 2.0 and dr < 1.0
    assert read_ply(out).extra["views"].max() == 2
