import numpy as np

from canopy_stereo.geometry.camera import project
from canopy_stereo.geometry.rectification import fusiello_rectify
from canopy_stereo.geometry.triangulation import (
    apply_homography,
    backmap_matches,
    organized_from_disparity,
    triangulate_disparity,
    triangulate_disparity_points,
    triangulate_dlt,
)


def _scene(rng, n):
    return np.column_stack([rng.uniform(-200, 250, n), rng.uniform(-200, 100, n), rng.uniform(400, 900, n)])


def test_exact_projections_triangulate_exactly(paper_rig, rng):
    X = _scene(rng, 5000)
    Xe = triangulate_dlt(paper_rig.P_left, paper_rig.P_right, project(paper_rig.P_left, X),
                         project(paper_rig.P_right, X))
    rel = np.linalg.norm(Xe - X, axis=1) / np.linalg.norm(X, axis=1)
    assert rel.max() < 1e-6


def test_points_behind_a_camera_are_dropped(paper_rig):
    X = np.array([[50.0, -60.0, 600.0], [50.0, -60.0, -600.0]])
    Xe = triangulate_dlt(paper_rig.P_left, paper_rig.P_right, project(paper_rig.P_left, X),
                         project(paper_rig.P_right, X))
    assert np.all(np.isfinite(Xe[0])) and np.all(np.isnan(Xe[1]))


def test_backmapped_rectified_matches_triangulate_to_the_points(paper_rig, rng):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    X = _scene(rng, 2000)
    pl = apply_homography(rect.H_left, project(paper_rig.P_left, X))
    pr = apply_homography(rect.H_right, project(paper_rig.P_right, X))
    xl, xr = backmap_matches(pl[:, 0], pl[:, 1], pl[:, 0] - pr[:, 0], rect)
    Xe = triangulate_dlt(paper_rig.P_left, paper_rig.P_right, xl, xr)
    assert np.abs(Xe - X).max() < 1e-6


def test_plane_disparity_gives_plane_on_both_grids(paper_rig):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    f, B = rect.focal_length, rect.baseline
    Z = 600.0  # a fronto-parallel plane in the rectified camera frame
    w, h = rect.size
    disp = np.full((h, w), f * B / Z + rect.doffs, np.float32)
    disp[:10] = -1
    cloud = triangulate_disparity(disp, rect, paper_rig.P_left, paper_rig.P_right)
    assert np.all(np.isnan(cloud[:10]))
    depth = (cloud[10:].reshape(-1, 3) - rect.P_rect_left[:, :3].T @ np.zeros(3)) @ rect.R_rect[2]
    c_left = -np.linalg.solve(rect.P_rect_left[:, :3], rect.P_rect_left[:, 3])
    depth = (cloud[10:].reshape(-1, 3) - c_left) @ rect.R_rect[2]
    assert np.allclose(depth, Z, atol=1e-6)
    org = organized_from_disparity(disp, rect, paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    ok = np.all(np.isfinite(org), axis=2)
    assert ok.mean() > 0.8
    assert np.allclose((org[ok] - c_left) @ rect.R_rect[2], Z, atol=1e-6)
    # every valid organized point projects back onto its own left pixel
    vv, uu = np.nonzero(ok)
    assert np.abs(project(paper_rig.P_left, org[ok]) - np.column_stack([uu, vv])).max() < 1e-6


def test_one_pass_points_equal_the_grid_triangulation(paper_rig, rng):
    """triangulate_disparity_points (the node's kernel) = triangulate_disparity, bit for bit
    in float64 before the float32 cast: valid pixels, scale, mask and organized layout."""
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    w, h = rect.size
    disp = rng.uniform(20, 60, size=(h, w)).astype(np.float32)
    disp[rng.random((h, w)) < 0.3] = -1
    disp[5, 5] = np.nan
    mask = (rng.random((h, w)) < 0.8).astype(np.uint8) * 255
    grid = triangulate_disparity(disp, rect, paper_rig.P_left, paper_rig.P_right)
    pts, index = triangulate_disparity_points(disp, rect, paper_rig.P_left, paper_rig.P_right, scale=1e-3)
    valid = np.isfinite(grid).all(axis=2).ravel()
    np.testing.assert_array_equal(index, np.flatnonzero(valid))
    np.testing.assert_array_equal(pts, (grid.reshape(-1, 3)[valid] * 1e-3).astype(np.float32))
    mpts, mindex = triangulate_disparity_points(disp, rect, paper_rig.P_left, paper_rig.P_right, mask=mask)
    np.testing.assert_array_equal(mindex, np.flatnonzero(valid & (mask.ravel() > 0)))
    org, oindex = triangulate_disparity_points(disp, rect, paper_rig.P_left, paper_rig.P_right, organized=True)
    assert org.shape == (h * w, 3) and np.array_equal(oindex, np.arange(h * w))
    np.testing.assert_array_equal(np.isnan(org[:, 0]), ~valid)
