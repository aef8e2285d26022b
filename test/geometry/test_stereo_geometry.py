"""Standard stereo geometry: what image_geometry / stereo_image_proc compute from our messages.

The consumer side is implemented here independently, from the formulas of
image_geometry's ``StereoCameraModel`` (Q from the two rectified CameraInfo ``P``
matrices) and stereo_image_proc's point cloud (``cv2.reprojectImageTo3D`` with that Q).
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.geometry.camera import decompose_projection, point_depth, project
from canopy_stereo.geometry.rectification import StereoRectifier, fusiello_rectify
from canopy_stereo.geometry.triangulation import apply_homography
from test.support.rigs import unequal_verged_rig


def image_geometry_Q(info_left, info_right) -> np.ndarray:
    """image_geometry StereoCameraModel::updateQ, from the two CameraInfo messages' P."""
    Pl = np.asarray(info_left.p, np.float64).reshape(3, 4)
    Pr = np.asarray(info_right.p, np.float64).reshape(3, 4)
    fx, fy, cx, cy = Pl[0, 0], Pl[1, 1], Pl[0, 2], Pl[1, 2]
    baseline = -Pr[0, 3] / Pr[0, 0]          # StereoCameraModel::baseline()
    Tx = -baseline
    Q = np.zeros((4, 4))
    Q[0, 0] = fy * Tx
    Q[0, 3] = -fy * cx * Tx
    Q[1, 1] = fx * Tx
    Q[1, 3] = -fx * cy * Tx
    Q[2, 3] = fx * fy * Tx
    Q[3, 2] = -fy
    Q[3, 3] = fy * (cx - Pr[0, 2])
    return Q


def test_fusiello_shares_one_principal_point_and_keeps_images_in_view(paper_rig):
    for rig in (paper_rig, unequal_verged_rig()):
        rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
        assert np.array_equal(rect.K_rect_left, rect.K_rect_right) and rect.doffs == 0.0
        w, h = rig.image_size
        vv, uu = np.mgrid[0:h:8, 0:w:8]
        grid = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
        for H_inv in (rect.H_left_inv, rect.H_right_inv):
            src = apply_homography(H_inv, grid)
            inside = (src[:, 0] >= 0) & (src[:, 0] <= w - 1) & (src[:, 1] >= 0) & (src[:, 1] <= h - 1)
            assert inside.mean() > 0.85     # the rectified image is mostly picture, not border
        # the left (reference) image stays centred as with per-camera principal points
        centre = np.array([[(w - 1) / 2.0, (h - 1) / 2.0]])
        c_left = apply_homography(rect.H_left, centre)[0]
        assert abs(c_left[0] - centre[0, 0]) < 1e-6 and abs(c_left[1] - centre[0, 1]) < 40
        # points at infinity have zero disparity; rows agree
        far = np.array([[0.0, 0.0, 1e9], [3e8, -2e8, 1e9]])
        pl = project(rect.P_rect_left, far)
        pr = project(rect.P_rect_right, far)
        assert np.allclose(pl, pr, atol=1e-3)


@pytest.mark.slow
def test_q_matrix_depth_equals_f_t_over_d_and_the_truth_on_a_verged_rig():
    """Must-show: a verged rig whose cameras differ in principal point, rendered by
    canopy_stereo.sim; DisparityImage + the two rectified CameraInfos through
    image_geometry's Q give f*t/d within 0.1 %, and both the scene's truth within 1 %."""
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.geometry.rectification import default_disparity_range
    from canopy_stereo.io.images import to_gray
    from canopy_stereo.sim import render_scene

    convert = pytest.importorskip("canopy_stereo.ros.convert")
    rig = unequal_verged_rig()
    sim = render_scene("croton", rig, seed=3)
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    left_r, right_r = StereoRectifier(rig, rect).rectify(sim.left, sim.right)
    dmin, dmax = default_disparity_range(rect)
    disp = compute_disparity(to_gray(left_r), to_gray(right_r), matcher="sgbm", disp_min=dmin,
                             disp_max=dmax)
    t_m = rect.baseline * rig.metres_per_unit
    msg = convert.disparity_to_msg(disp, rect.focal_length, t_m, dmin, dmax, doffs=rect.doffs)
    info_l = convert.rectified_camera_info(rect.K_rect_left, rect.size, t_m, "left")
    info_r = convert.rectified_camera_info(rect.K_rect_right, rect.size, t_m, "right")

    # consumer side: the DisparityImage as stereo_image_proc reads it
    d = np.frombuffer(bytes(msg.image.data), "<f4").reshape(msg.image.height, msg.image.width)
    valid = (d >= msg.min_disparity) & (d <= msg.max_disparity) & (d > 0)
    z_ft = np.where(valid, msg.f * msg.t / np.where(valid, d, 1.0), np.nan)
    Q = image_geometry_Q(info_l, info_r)
    xyz = cv2.reprojectImageTo3D(np.where(valid, d, 0).astype(np.float32), Q.astype(np.float32),
                                 handleMissingValues=True)
    z_q = np.where(valid, xyz[..., 2].astype(np.float64), np.nan)
    ok = valid & np.isfinite(z_q)
    assert ok.sum() > 50_000
    assert np.nanmax(np.abs(z_q[ok] - z_ft[ok]) / z_ft[ok]) < 1e-3

    # truth: the rectified left pixel's ray hits the scene where the left camera saw it
    vv, uu = np.nonzero(ok)
    X_rect_mm = xyz[vv, uu].astype(np.float64) / rig.metres_per_unit
    X_world = X_rect_mm @ rect.R_rect + decompose_projection(rig.P_left).C
    q = np.rint(project(rig.P_left, X_world)).astype(int)
    w, h = rig.image_size
    inside = (q[:, 0] >= 0) & (q[:, 0] < w) & (q[:, 1] >= 0) & (q[:, 1] < h)
    q, X_world, z_ft_sel = q[inside], X_world[inside], z_ft[vv, uu][inside]
    leaf = sim.leaf_ids_left[q[:, 1], q[:, 0]] > 0
    truth = sim.xyz_left[q[leaf, 1], q[leaf, 0]]
    z_true = point_depth(rect.P_rect_left, truth) * rig.metres_per_unit
    z_from_q = point_depth(rect.P_rect_left, X_world[leaf]) * rig.metres_per_unit
    assert leaf.sum() > 20_000
    assert np.median(np.abs(z_from_q - z_true) / z_true) < 0.01
    assert np.median(np.abs(z_ft_sel[leaf] - z_true) / z_true) < 0.01
    # and the metric scale (signed) is right, not only the spread
    assert np.median(z_from_q / z_true) == pytest.approx(1.0, abs=0.005)
