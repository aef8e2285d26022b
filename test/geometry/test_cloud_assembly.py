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
