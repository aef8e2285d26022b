"""The point cloud node's arithmetic in the core (canopy_stereo.geometry.cloud_assembly), no ROS."""
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.cloud_assembly import cloud_from_disparity, disparity_image_reprojection
from canopy_stereo.geometry.frames import rectified_projection, reproject_disparity, reprojection_matrix
from canopy_stereo.geometry.rectification import fusiello_rectify
from canopy_stereo.geometry.triangulation import triangulate_disparity


def test_disparity_image_q_is_the_rep104_pair_with_reduced_disparities():
    K = np.array([[640.0, 0, 320.5], [0, 641.0, 240.25], [0, 0, 1]])
    Pl, Pr = rectified_projection(K, 0.06, "left"), rectified_projection(K, 0.06, "right")
    Q = disparity_image_reprojection(640.0, 0.06, Pl)
    np.testing.assert_allclose(Q, reprojection_matrix(Pl, Pr), rtol=1e-12, atol=1e-12)
    d = np.full((4, 5), 32.0)  # Z = f t / d = 1.2 m everywhere
    np.testing.assert_allclose(reproject_disparity(d, Q)[..., 2], 640.0 * 0.06 / 32.0)
    for f, t in ((0.0, 0.06), (640.0, 0.0)):
        with pytest.raises(CanopyStereoError, match="no focal length/baseline"):
            disparity_image_reprojection(f, t, Pl)


def test_cloud_from_disparity_is_the_triangulation_with_its_colours(paper_rig):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    w, h = rect.size
    rng = np.random.default_rng(0)
    disp = rng.uniform(20.0, 40.0, (h, w)).astype(np.float32)
    disp[::5] = -1
    colours = rng.integers(0, 255, (h, w)).astype(np.float32)
    pts, cols = cloud_from_disparity(disp, colours, rect, paper_rig.P_left, paper_rig.P_right,
                                     scale=0.001, organized=False)
    ref = triangulate_disparity(disp, rect, paper_rig.P_left, paper_rig.P_right)
    valid = disp >= 0
    np.testing.assert_allclose(pts, ref[valid] * 0.001, rtol=1e-5)
    np.testing.assert_array_equal(cols, colours[valid])
    grid, same = cloud_from_disparity(disp, colours, rect, paper_rig.P_left, paper_rig.P_right,
                                      scale=0.001, organized=True)
    assert grid.shape == (h, w, 3) and same is colours and np.isnan(grid[~valid]).all()
    with pytest.raises(CanopyStereoError, match="colour image is"):
        cloud_from_disparity(disp, colours[:-1], rect, paper_rig.P_left, paper_rig.P_right)


def test_a_window_of_the_disparity_gives_the_points_of_the_full_image():
    """point_cloud_node reprojects only the DisparityImage's valid_window: the crop with the
    offset Q gives the full image's points (same order: rows of the window), to float rounding."""
    from canopy_stereo.geometry.cloud_assembly import offset_reprojection, window_slices
    from canopy_stereo.geometry.frames import reproject_disparity_points

    rng = np.random.default_rng(3)
    disp = np.full((48, 64), np.nan, np.float32)
    disp[10:30, 20:50] = rng.uniform(5.0, 20.0, (20, 30)).astype(np.float32)
    K = np.array([[640.3, 0, 31.7], [0, 641.1, 23.2], [0, 0, 1]])
    Q = disparity_image_reprojection(640.3, 0.06, rectified_projection(K, 0.06, "left"))
    rows, cols = window_slices((20, 10, 30, 20), disp.shape)
    assert (rows, cols) == (slice(10, 30), slice(20, 50))
    full, _, depth_full = reproject_disparity_points(disp, Q)
    kept, _, depth = reproject_disparity_points(disp[rows, cols], offset_reprojection(Q, cols.start, rows.start))
    assert full.shape == kept.shape and len(full) == 600
    np.testing.assert_allclose(kept, full, rtol=1e-6)
    np.testing.assert_allclose(depth, depth_full[rows, cols], rtol=1e-6)
    assert window_slices((0, 0, 0, 0), disp.shape) == (slice(0, 48), slice(0, 64))  # unset: everything
    assert window_slices((60, 40, 30, 30), disp.shape) == (slice(40, 48), slice(60, 64))  # clipped
