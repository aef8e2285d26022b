import numpy as np
import pytest

from canopy_stereo.geometry.camera import project
from canopy_stereo.geometry.distortion import distort_pixels, undistort_pixels
from canopy_stereo.geometry.rectification import StereoRectifier, fusiello_rectify, hartley_rectify
from canopy_stereo.geometry.triangulation import apply_homography


def _scene(rng, n):
    return np.column_stack([rng.uniform(-200, 250, n), rng.uniform(-200, 100, n), rng.uniform(400, 900, n)])


def test_fusiello_rows_agree(paper_rig, rng):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    X = _scene(rng, 3000)
    pl = apply_homography(rect.H_left, project(paper_rig.P_left, X))
    pr = apply_homography(rect.H_right, project(paper_rig.P_right, X))
    assert np.abs(pl[:, 1] - pr[:, 1]).max() < 0.01
    d = pl[:, 0] - pr[:, 0]
    assert np.all(d > 0)
    # disparity follows f B / Z in the rectified frame
    c = -np.linalg.solve(rect.P_rect_left[:, :3], rect.P_rect_left[:, 3])
    Z = (X - c) @ rect.R_rect[2]
    assert np.allclose(d, rect.focal_length * rect.baseline / Z + rect.doffs, atol=1e-6)
    # new cameras keep the old centres
    assert np.allclose(project(rect.P_rect_left, X), pl, atol=1e-6)


def test_hartley_from_matches_aligns_rows(paper_rig, rng):
    X = _scene(rng, 400)
    xl = project(paper_rig.P_left, X) + rng.normal(0, 0.1, (400, 2))
    xr = project(paper_rig.P_right, X) + rng.normal(0, 0.1, (400, 2))
    rect = hartley_rectify(xl, xr, paper_rig.image_size)
    X2 = _scene(rng, 1000)
    pl = apply_homography(rect.H_left, project(paper_rig.P_left, X2))
    pr = apply_homography(rect.H_right, project(paper_rig.P_right, X2))
    assert np.median(np.abs(pl[:, 1] - pr[:, 1])) < 0.3
    d = pl[:, 0] - pr[:, 0]
    lo, hi = rect.disparity_range
    assert np.mean((d >= lo) & (d <= hi)) > 0.98
    # not mirrored: left-right order and up-down order of points are kept
    assert np.corrcoef(pl[:, 0], project(paper_rig.P_left, X2)[:, 0])[0, 1] > 0.9
    assert np.corrcoef(pl[:, 1], project(paper_rig.P_left, X2)[:, 1])[0, 1] > 0.9


def test_distortion_round_trip(paper_rig, rng):
    D = np.array([-0.26, -0.05, 0.002, -0.0003, 0.25])
    xy = np.column_stack([rng.uniform(0, 640, 500), rng.uniform(0, 480, 500)])
    back = undistort_pixels(paper_rig.P_left, D, distort_pixels(paper_rig.P_left, D, xy))
    assert np.abs(back - xy).max() < 1e-6


def test_rectifier_moves_pixels_where_homography_says(paper_rig):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    img = np.zeros((480, 640), np.uint8)
    img[200:203, 300:303] = 255
    lr, _ = StereoRectifier(paper_rig, rect).rectify(img, img)
    v, u = np.nonzero(lr > 128)
    expect = apply_homography(rect.H_left, np.array([[301.0, 201.0]]))[0]
    assert abs(u.mean() - expect[0]) < 0.6 and abs(v.mean() - expect[1]) < 0.6


def test_real_chessboard_rig(shared_data):
    from canopy_stereo.geometry.chessboard import calibrate_stereo_chessboard, detect_stereo_chessboards
    from canopy_stereo.io.images import ImageFiles

    d = shared_data / "opencv_stereo_calib_chessboard"
    lefts, rights = ImageFiles(str(d / "left*.jpg"), color=False), ImageFiles(str(d / "right*.jpg"), color=False)
    cal = calibrate_stereo_chessboard(lefts, rights, pattern=(9, 6), square_size=25.0)
    assert cal.rms_stereo <= 0.5
    rect = fusiello_rectify(cal.P_left, cal.P_right, (640, 480))
    views = detect_stereo_chessboards(lefts, rights)
    dv = []
    for cl, cr in zip(views.left, views.right):
        pl = apply_homography(rect.H_left, undistort_pixels(cal.P_left, cal.D_left, cl))
        pr = apply_homography(rect.H_right, undistort_pixels(cal.P_right, cal.D_right, cr))
        dv.append(pl[:, 1] - pr[:, 1])
    assert np.median(np.abs(np.concatenate(dv))) <= 0.5
    # corners triangulate back close to the board model (25 mm squares)
    assert np.all(cal.check.mean_abs < [1.0, 1.0, 2.0])


@pytest.mark.slow
def test_hartley_from_pooled_qdmatch_on_raw_chessboard_pairs(shared_data):
    """Issue 6 target: Hartley from quasi-dense matches, corners' median |dv| <= 0.5 px."""
    from canopy_stereo.geometry.board_corners import detect_board_corners
    from canopy_stereo.geometry.chessboard import calibrate_stereo_chessboard
    from canopy_stereo.io.images import ImageFiles, read_image
    from canopy_stereo.io.rig import Rig
    from canopy_stereo.pipeline.reconstruct import rectify_rig

    d = shared_data / "opencv_stereo_calib_chessboard"
    cal = calibrate_stereo_chessboard(ImageFiles(str(d / "left*.jpg"), color=False),
                                      ImageFiles(str(d / "right*.jpg"), color=False), pattern=(9, 6), square_size=25.0)
    rig = Rig(cal.P_left, cal.P_right, (640, 480), D_left=cal.D_left, D_right=cal.D_right)
    names = ["01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14"]
    pairs = [(read_image(d / f"left{n}.jpg"), read_image(d / f"right{n}.jpg")) for n in names]
    rect = rectify_rig(rig, "hartley", match_pairs=pairs)
    dv = []
    for left, right in pairs:
        cl, cr = detect_board_corners(left[:, :, 0], (9, 6)), detect_board_corners(right[:, :, 0], (9, 6))
        pl = apply_homography(rect.H_left, undistort_pixels(rig.P_left, rig.D_left, cl))
        pr = apply_homography(rect.H_right, undistort_pixels(rig.P_right, rig.D_right, cr))
        dv.append(pl[:, 1] - pr[:, 1])
    assert np.median(np.abs(np.concatenate(dv))) <= 0.5


def test_cached_rectifier_is_reused_only_for_the_same_geometry(paper_rig):
    import dataclasses

    from canopy_stereo.geometry.rectification import StereoRectifier, cached_rectifier

    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    a = cached_rectifier(paper_rig, rect)
    same = dataclasses.replace(paper_rig, P_left=paper_rig.P_left.copy())  # equal values, new arrays
    assert cached_rectifier(same, fusiello_rectify(same.P_left, same.P_right, same.image_size)) is a
    distorted = dataclasses.replace(paper_rig, D_left=np.array([0.05, 0.0, 0.0, 0.0, 0.0]))
    b = cached_rectifier(distorted, rect)
    assert b is not a
    img = np.random.default_rng(0).integers(0, 256, (paper_rig.image_size[1], paper_rig.image_size[0], 3), np.uint8)
    for rectifier, rig in ((a, paper_rig), (b, distorted)):
        want = StereoRectifier(rig, rect).rectify(img, img)
        got = rectifier.rectify(img, img)
        assert all(np.array_equal(g, w) for g, w in zip(got, want))


@pytest.mark.parametrize("distortion", [(0.0, 0.0, 0.0, 0.0, 0.0), (-0.28, 0.09, 0.001, -0.0005, 0.0)])
def test_fixed_point_maps_resample_as_float_maps(paper_rig, rng, distortion):
    """Issue 28: the rectifier's fixed-point maps (``cv2.convertMaps`` to CV_16SC2, 1/32 pixel)
    give the images float maps give, within a grey level on average (a textured colour image,
    with and without lens distortion); :meth:`StereoRectifier.coordinates` are the fixed maps'
    positions."""
    import cv2

    from canopy_stereo.io.rig import Rig

    D = np.array(distortion)
    rig = Rig(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size, paper_rig.world_unit, D, D,
              dict(paper_rig.extra))
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    rectifier = StereoRectifier(rig, rect)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (480, 640, 3)).astype(np.float32), (0, 0), 1.5)
    img = np.clip(np.rint((texture - texture.mean()) * 4 + 128), 0, 255).astype(np.uint8)
    w, h = rect.size
    vv, uu = np.mgrid[0:h, 0:w]
    raw = distort_pixels(rig.P_right, rig.D_right,
                         apply_homography(rect.H_right_inv, np.column_stack([uu.ravel(), vv.ravel()]).astype(float)))
    map_x, map_y = (raw[:, i].reshape(h, w).astype(np.float32) for i in (0, 1))
    coords = rectifier.coordinates("right")
    inside = (map_x > 1) & (map_x < 638) & (map_y > 1) & (map_y < 478)
    assert inside.mean() > 0.8
    assert np.abs(coords[..., 0] - map_x)[inside].max() <= 1 / 64 + 1e-3
    assert np.abs(coords[..., 1] - map_y)[inside].max() <= 1 / 64 + 1e-3
    for image in (img, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)):
        fixed = rectifier.rectify_one(image, "right").astype(float)
        exact = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT).astype(float)
        assert np.abs(fixed - exact)[inside].mean() <= 1.0
        assert np.abs(fixed - exact)[inside].max() <= 3


def test_an_identity_rectification_is_not_resampled(paper_rig, rng):
    """Issue 28: a pair that comes rectified (the bundled Plants rig: one K, parallel cameras,
    no distortion) has identity maps; its images come back bit for bit what the remap gives
    (their own pixels), without it, and with ``copy=False`` as the very input. A real rig's
    maps (the paper rig: rotated cameras) are resampled as before."""
    import cv2

    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_rig

    rig = load_rig(bundled_rig("plants"))
    rectifier = StereoRectifier(rig, fusiello_rectify(rig.P_left, rig.P_right, rig.image_size))
    assert rectifier.identity == (True, True)
    w, h = rig.image_size
    bgr = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    for side, image in (("left", bgr), ("right", bgr[..., 1].copy())):
        m1, m2 = rectifier._maps[0 if side == "left" else 1]
        remapped = cv2.remap(image, m1, m2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        copied = rectifier.rectify_one(image, side)
        assert np.array_equal(copied, remapped) and copied is not image
        assert rectifier.rectify_one(image, side, copy=False) is image
    assert not np.array_equal(rectifier.rectify_one(bgr[:-2], "left"), bgr[:-2])  # another size: remapped
    paper = StereoRectifier(paper_rig, fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size))
    assert paper.identity == (False, False)
