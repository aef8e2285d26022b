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


def _naive_records(disp, Q, T, mask, organized, rgb_bits):
    """The records kernel's arithmetic per pixel in plain numpy (float64, then float32)."""
    h, w = disp.shape
    rows, depth = [], np.full((h, w), np.nan, np.float32)
    for v in range(h):
        for u in range(w):
            d = float(disp[v, u])
            with np.errstate(divide="ignore", invalid="ignore"):
                iw = np.float64(1.0) / (Q[3, 2] * np.float64(d) + Q[3, 3])
                x, y, z = (Q[0, 0] * u + Q[0, 3]) * iw, (Q[1, 1] * v + Q[1, 3]) * iw, Q[2, 3] * iw
            ok = d > 0 and z > 0 and np.isfinite(z) and (mask is None or mask[v, u] != 0)
            if ok:
                depth[v, u] = z
                p = [T[k, 0] * x + T[k, 1] * y + T[k, 2] * z + T[k, 3] for k in range(3)]
            elif organized:
                p = [np.nan] * 3
            else:
                continue
            rows.append(np.array(p, np.float32).view(np.uint32).tolist() + [int(rgb_bits[v, u])])
    return np.array(rows, np.uint32).reshape(-1, 4), depth


@pytest.mark.parametrize("organized", [False, True])
def test_records_kernel_is_the_naive_arithmetic_bit_for_bit(organized):
    from canopy_stereo.geometry.frames import reproject_disparity_records

    rng = np.random.default_rng(4)
    for trial in range(6):
        h, w = (int(v) for v in rng.integers(3, 30, 2))
        disp = (rng.random((h, w)) * 90 - 5).astype(np.float32)
        disp[rng.random((h, w)) < 0.2] = np.nan
        disp[rng.random((h, w)) < 0.03] = np.inf
        Q = np.array([[1, 0, 0, -w / 2 + rng.random()], [0, 1, 0, -h / 2], [0, 0, 0, 600 + rng.random()],
                      [0, 0, 1 / 0.12, -3 * rng.random()]])
        T = np.eye(4)
        T[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        T[:3, 3] = rng.normal(size=3)
        mask = (rng.random((h, w)) > 0.3).astype(np.uint8) * 255 if trial % 2 else None
        rgb = rng.random((h, w)).astype(np.float32)
        records, depth = reproject_disparity_records(disp, Q, T=T, rgb=rgb, mask=mask, organized=organized)
        ref, ref_depth = _naive_records(disp, Q, T, mask, organized, rgb.view(np.uint32))
        assert np.array_equal(records.view(np.uint32), ref)
        assert np.array_equal(depth.view(np.uint32), ref_depth.view(np.uint32))


@pytest.mark.parametrize("organized", [False, True])
def test_records_kernel_reads_windows_in_place_and_skips_the_depth_on_request(organized):
    """Windows of the disparity and the mask (not contiguous, as point_cloud_node passes its
    valid_window) give the naive arithmetic's records bit for bit, with or without depth."""
    from canopy_stereo.geometry.frames import reproject_disparity_records

    rng = np.random.default_rng(6)
    h, w = 37, 53
    disp = (rng.random((h, w)) * 80 - 5).astype(np.float32)
    disp[rng.random((h, w)) < 0.25] = np.nan
    mask = (rng.random((h, w)) > 0.6).astype(np.uint8) * 255
    rgb = rng.random((h, w)).astype(np.float32)
    Q = np.array([[1, 0, 0, -20.5], [0, 1, 0, -15.0], [0, 0, 0, 610.0], [0, 0, 1 / 0.1, -1.5]])
    T = np.eye(4)
    T[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    T[:3, 3] = rng.normal(size=3)
    rows, cols = slice(4, 31), slice(7, 45)
    ref, ref_depth = _naive_records(np.ascontiguousarray(disp[rows, cols]), Q, T,
                                    np.ascontiguousarray(mask[rows, cols]), organized,
                                    np.ascontiguousarray(rgb[rows, cols]).view(np.uint32))
    for depth in (True, False):
        records, depth_image = reproject_disparity_records(disp[rows, cols], Q, T=T, rgb=rgb[rows, cols],
                                                           mask=mask[rows, cols], organized=organized,
                                                           depth=depth)
        assert np.array_equal(records.view(np.uint32), ref)
        if depth:
            assert np.array_equal(depth_image.view(np.uint32), ref_depth.view(np.uint32))
        else:
            assert depth_image is None


def test_records_from_bgr_are_the_records_from_packed_rgb():
    """``bgr=`` (a window of the colour image, packed for the kept points only) gives the bits
    of ``rgb=pack_bgr_image(bgr)``."""
    from canopy_stereo.geometry.frames import reproject_disparity_records
    from canopy_stereo.ros.convert import pack_bgr_image

    rng = np.random.default_rng(5)
    disp = (rng.random((40, 50)) * 60).astype(np.float32)
    disp[rng.random(disp.shape) < 0.3] = np.nan
    bgr = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    Q = np.array([[1, 0, 0, -25.0], [0, 1, 0, -20.0], [0, 0, 0, 500.0], [0, 0, 10.0, 0]])
    rows, cols = slice(3, 37), slice(5, 44)
    for organized in (False, True):
        a, da = reproject_disparity_records(disp[rows, cols], Q, bgr=bgr[rows, cols], organized=organized)
        b, db = reproject_disparity_records(disp[rows, cols], Q, rgb=pack_bgr_image(bgr[rows, cols]),
                                            organized=organized)
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32)) and np.array_equal(da, db, equal_nan=True)
    with pytest.raises(ValueError, match="exactly one"):
        reproject_disparity_records(disp, Q)
    with pytest.raises(ValueError, match="uint8"):
        reproject_disparity_records(disp, Q, bgr=bgr[:, :, :2])
