"""Feature matching study and quasi-dense matching (issue 6), on generated pairs.

The pairs are generated (:mod:`canopy_stereo.sim.stereo_pair`): a textured
left image and a right image warped from it with a known disparity (a slanted
plane), so every match can be checked against the truth without shared data.
"""
from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError, ImageError, MatchingError
from canopy_stereo.features import (
    METHODS,
    MatchResult,
    distribution,
    epipolar_distance,
    estimate_fundamental,
    match_pair,
    method_available,
)
from canopy_stereo.features.quasi_dense import propagate, resample, sift_seeds
from canopy_stereo.features.study import gt_correctness, run_study
from canopy_stereo.sim.stereo_pair import slanted_plane_pair


@pytest.fixture(scope="module")
def slanted_pair():
    """(left, right, disparity): the right image sees left pixel (u, v) at (u - d, v)."""
    return slanted_plane_pair(240, 180, texture_scale=2.0)


# ----------------------------------------------------------------------------- distribution


def test_distribution_counts_8px_cells_as_the_paper_defines():
    # the paper's example: 31 matches in 20 cells of a 640x480 image -> 20 / 4800 = 0.42 %
    cells = [(cx, cy) for cx, cy in zip(range(0, 80, 4), range(0, 60, 3))]
    assert len(cells) == 20
    pts = [(8 * cx + 3.0, 8 * cy + 3.0) for cx, cy in cells]
    pts += [(8 * cx + 0.0, 8 * cy + 7.0) for cx, cy in cells[:11]]      # same cells again
    pts = np.array(pts)
    assert len(pts) == 31
    assert distribution(pts, (640, 480)) == pytest.approx(20 / 4800)
    assert round(100 * distribution(pts, (640, 480)), 2) == 0.42


def test_distribution_cell_boundaries_and_partial_cells():
    # pixel i covers [i - 0.5, i + 0.5): u = 7.49 is still cell 0, u = 7.5 is cell 1
    assert distribution([[7.49, 0.0]], (16, 8)) == pytest.approx(1 / 2)
    assert distribution([[7.49, 0.0], [7.5, 0.0]], (16, 8)) == pytest.approx(2 / 2)
    assert distribution([[-0.5, -0.5]], (16, 8)) == pytest.approx(1 / 2)
    # 20 x 10 pixels -> 3 x 2 cells (the last column and row are partial but count)
    pts = [[19.0, 9.0], [0.0, 0.0]]
    assert distribution(pts, (20, 10)) == pytest.approx(2 / 6)
    # points outside the image are ignored; none -> 0
    assert distribution([[20.0, 0.0], [-1.0, 3.0], [5.0, 10.2]], (20, 10)) == 0.0
    assert distribution(np.zeros((0, 2)), (20, 10)) == 0.0


# ----------------------------------------------------------------------------- F estimation


def _two_view(rng, n=200, n_out=60):
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    X = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.8, 0.8, n), rng.uniform(3, 8, n)])
    a = 0.1
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    t = np.array([[-0.5], [0.05], [0.1]])
    x1 = (K @ X.T).T
    x1 = x1[:, :2] / x1[:, 2:]
    x2 = (K @ (R @ X.T + t)).T
    x2 = x2[:, :2] / x2[:, 2:]
    x1 += rng.normal(0, 0.2, x1.shape)
    x2 += rng.normal(0, 0.2, x2.shape)
    x2[:n_out] = rng.uniform([0, 0], [640, 480], (n_out, 2))
    return x1, x2, n_out


@pytest.mark.parametrize("method", ["ransac", "magsac"])
def test_estimate_fundamental_separates_outliers(rng, method):
    x1, x2, n_out = _two_view(rng)
    F, inl = estimate_fundamental(x1, x2, method=method, threshold_px=1.0)
    assert F.shape == (3, 3) and np.isclose(np.linalg.norm(F), 1.0)
    good = np.zeros(len(x1), bool)
    good[n_out:] = True
    assert inl[good].mean() > 0.95
    d_out = epipolar_distance(F, x1[:n_out], x2[:n_out])
    assert inl[~good].sum() <= np.sum(d_out <= 1.0)          # only outliers that lie on their line
    assert np.median(epipolar_distance(F, x1[good], x2[good], symmetric=True)) < 0.5


def test_estimate_fundamental_rejects_bad_input():
    with pytest.raises(MatchingError, match="at least 8"):
        estimate_fundamental(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(CanopyStereoError, match="unknown F estimation method"):
        estimate_fundamental(np.zeros((10, 2)), np.zeros((10, 2)), method="lmeds")
    with pytest.raises(CanopyStereoError, match="different numbers"):
        estimate_fundamental(np.zeros((10, 2)), np.zeros((9, 2)))


# ----------------------------------------------------------------------------- sparse matching


def _share_correct(res, d):
    share, n = gt_correctness(res.x_left, res.x_right, d)
    assert n == len(res.x_left)  # the truth is known at every match of the slanted pair
    return share


def test_sift_matches_are_verified_and_correct(slanted_pair):
    left, right, d = slanted_pair
    t0 = time.perf_counter()
    res = match_pair(left, right, method="sift")
    wall = time.perf_counter() - t0
    assert isinstance(res, MatchResult) and res.method == "sift"
    assert res.x_left.dtype == np.float64 and res.x_left.shape == res.x_right.shape
    assert res.num >= 50 and res.num_left >= res.num and res.num_right >= res.num
    # stage times: each measured, together no more than the call took
    assert min(res.t_left, res.t_right, res.t_match) > 0 and res.t_left + res.t_right + res.t_match <= wall
    assert res.t_propagation is None and res.t_resample is None
    assert _share_correct(res, d) >= 0.95
    # every kept match lies on the epipolar line of the F that verified it
    assert np.all(epipolar_distance(res.F, res.x_left, res.x_right) <= 1.0 + 1e-6)


@pytest.mark.parametrize("method", ["orb", "asift", "harris-affine", "hessian-affine"])
def test_other_methods_match_correctly(slanted_pair, method):
    left, right, d = slanted_pair
    kw = {"max_tilt": 2.0} if method == "asift" else {}
    res = match_pair(left, right, method=method, min_matches=0, **kw)
    assert res.num >= 10, res.note
    assert _share_correct(res, d) >= 0.9


def test_asift_pools_more_features_than_sift(slanted_pair):
    left, right, _ = slanted_pair
    sift = match_pair(left, right, method="sift")
    asift = match_pair(left, right, method="asift", max_tilt=2.0)
    assert asift.num_left > 2 * sift.num_left
    assert asift.extras["num_views"] == 1 + 4 + 5


def test_asift_view_maps_original_pixels():
    from canopy_stereo.features.asift import simulate_view

    img = np.zeros((120, 160), np.uint8)
    cv2.circle(img, (110, 40), 3, 255, -1)
    view, mask, A = simulate_view(img, 2.0, 30.0)
    expected = A @ np.array([110.0, 40.0, 1.0])
    m = cv2.moments(view.astype(np.float32))
    centroid = np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])
    assert np.allclose(centroid, expected, atol=0.6)
    assert view.shape[1] < view.shape[0] * 2  # subsampled along x
    assert mask[int(expected[1]), int(expected[0])] == 255


def test_hessian_affine_recovers_the_shape_of_an_elongated_blob():
    from canopy_stereo.features.affine_regions import affine_adapt, scale_adapted_points

    # a dark elliptical Gaussian blob: axes 8 and 4 px, major axis at 30 degrees
    th = np.deg2rad(30.0)
    Rm = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    C = Rm @ np.diag([8.0 ** 2, 4.0 ** 2]) @ Rm.T
    u, v = np.meshgrid(np.arange(128.0), np.arange(128.0))
    p = np.stack([u - 64, v - 64], axis=-1)
    q = np.einsum("...i,ij,...j->...", p, np.linalg.inv(C), p)
    img = np.clip(200 - 150 * np.exp(-0.5 * q), 0, 255).astype(np.uint8)
    pts, sig, _ = scale_adapted_points(img, "hessian")
    X, U, _ = affine_adapt(img, pts, sig, kind="hessian")
    k = np.argmin(np.hypot(X[:, 0] - 64, X[:, 1] - 64))
    assert np.hypot(*(X[k] - 64)) < 1.5
    # the region shape U U^T is proportional to the blob covariance
    S = U[k] @ U[k].T
    vals, vecs = np.linalg.eigh(S)
    assert np.sqrt(vals[1] / vals[0]) == pytest.approx(2.0, rel=0.15)
    major = np.degrees(np.arctan2(vecs[1, 1], vecs[0, 1])) % 180
    assert abs(major - 30.0) < 8.0


# ----------------------------------------------------------------------------- quasi-dense


@pytest.mark.slow
def test_qdmatch_is_correct_and_better_spread_than_sift(slanted_pair):
    left, right, d = slanted_pair
    sift = match_pair(left, right, method="sift")
    t0 = time.perf_counter()
    qd = match_pair(left, right, method="qdmatch")
    wall = time.perf_counter() - t0
    assert qd.method == "qdmatch"
    stages = (qd.t_left, qd.t_right, qd.t_match, qd.t_propagation, qd.t_resample)
    assert min(stages) > 0 and sum(stages) <= wall  # each measured, together no more than the call
    assert qd.extras["num_propagated"] > 10 * qd.extras["num_seeds"]
    assert _share_correct(qd, d) >= 0.95
    assert qd.distribution > sift.distribution
    # resampled matches are region centres: at most one per 8x8 cell
    cells = np.floor((qd.x_left + 0.5) / 8).astype(int)
    assert len(np.unique(cells, axis=0)) == qd.num


def test_propagation_is_unique_and_respects_the_disparity_gradient_limit(slanted_pair):
    left, right, d = slanted_pair
    gl, gr = left, right                                     # grey uint8 already
    seeds = sift_seeds(gl, gr)
    eps, radius = 1, 1
    prop = propagate(gl, gr, seeds["x_left"], seeds["x_right"], radius=radius, eps=eps,
                     F=seeds["F"])
    assert len(prop) > 20 * prop.num_seeds
    # one match per left pixel and one per right pixel
    assert len(np.unique(prop.x_left, axis=0)) == len(prop)
    assert len(np.unique(prop.x_right, axis=0)) == len(prop)
    # seeds first (parent -1); every other match grew from an earlier neighbour whose
    # displacement differs by at most eps in each coordinate
    assert np.all(prop.parent[:prop.num_seeds] == -1)
    child = np.arange(prop.num_seeds, len(prop))
    par = prop.parent[child]
    assert np.all((par >= 0) & (par < child))
    assert np.abs(prop.x_left[child] - prop.x_left[par]).max() <= radius
    disp_child = prop.x_right[child] - prop.x_left[child]
    disp_par = prop.x_right[par] - prop.x_left[par]
    assert np.abs(disp_child - disp_par).max() <= eps
    assert prop.zncc.min() >= prop.params["zncc_min"]
    # and the pixel matches follow the truth
    share, _ = gt_correctness(prop.x_left, prop.x_right, d)
    assert share > 0.9


def test_resampling_fits_local_maps_to_an_exact_affine_field():
    from canopy_stereo.features.quasi_dense import Propagation

    # propagated matches of a 64x48 image under x' = 0.9 u + 0.05 v - 3, y' = v + 0.02 u
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    xl = np.column_stack([u.ravel(), v.ravel()]).astype(np.int32)
    xr_f = np.column_stack([0.9 * xl[:, 0] + 0.05 * xl[:, 1] - 3, xl[:, 1] + 0.02 * xl[:, 0]])
    ok = xr_f[:, 0] >= 0
    xl, xr_f = xl[ok], xr_f[ok]
    prop = Propagation(xl, np.rint(xr_f).astype(np.int32), np.ones(len(xl), np.float32),
                       np.full(len(xl), -1), len(xl), (64, 48), {})
    for model in ("affine", "homography"):
        cl, cr, support = resample(prop, model=model)
        assert len(cl) >= 40
        truth = np.column_stack([0.9 * cl[:, 0] + 0.05 * cl[:, 1] - 3, cl[:, 1] + 0.02 * cl[:, 0]])
        err = np.abs(cr - truth)
        assert err.max() <= 0.5                              # within the integer rounding
        assert err.mean() < 0.15                             # which the fit mostly averages out
        assert np.all((cl - 3.5) % 8 == 0)                    # cell centres
        assert np.all(support >= 12)


def test_qdmatch_on_textureless_images_gives_a_clear_message():
    flat = np.full((120, 160), 90, np.uint8)
    res = match_pair(flat, flat.copy(), method="qdmatch", min_matches=0)
    assert res.num == 0 and "no seeds" in res.note and "texture" in res.note
    with pytest.raises(MatchingError, match="no seeds"):
        match_pair(flat, flat.copy(), method="qdmatch")
    rows = run_study(flat, flat.copy(), methods=["sift", "qdmatch"])
    assert [r.result.num for r in rows] == [0, 0]
    assert "no seeds" in rows[1].result.note


def test_bad_input_is_reported():
    a = np.zeros((100, 120), np.uint8)
    with pytest.raises(ImageError, match="sizes differ"):
        match_pair(a, np.zeros((100, 121), np.uint8), method="sift")
    with pytest.raises(CanopyStereoError, match="unknown matching method 'sirf'"):
        match_pair(a, a, method="sirf")
    with pytest.raises(ImageError, match="uint8"):
        match_pair(a.astype(np.float32), a, method="sift")


def test_unavailable_methods_say_why_and_are_not_faked(slanted_pair):
    left, right, _ = slanted_pair
    ok, reason = method_available("surf")
    if not ok:
        assert "patented" in reason
        with pytest.raises(CanopyStereoError, match="patented"):
            match_pair(left, right, method="surf")
    rows = run_study(left, right, methods=["surf", "sift"])
    if not ok:
        assert rows[0].result.num == 0 and "patented" in rows[0].result.note
    assert set(METHODS) >= {"sift", "asift", "orb", "akaze", "kaze", "surf", "harris-affine",
                            "hessian-affine", "qdmatch"}


# ----------------------------------------------------------------------------- quasi-dense spread


def _split_pair(slanted_pair, band=(100, 140)):
    """The slanted pair with a flat vertical band cut through both images: two textured
    halves that propagation cannot cross."""
    left, right, d = slanted_pair
    left, right = left.copy(), right.copy()
    left[:, band[0]:band[1]] = 128
    right[:, band[0] - 20:band[1] - 5] = 128
    return left, right, d


def test_reseeding_reaches_a_textured_region_without_seeds(slanted_pair):
    left, right, d = _split_pair(slanted_pair)
    seeds = sift_seeds(left, right)
    only_left_half = seeds["x_left"][:, 0] < 90
    assert only_left_half.sum() >= 8 and (~only_left_half).sum() >= 8
    # the seeds taken away (right of the band) were good ones: reseeding replaces real seeds
    share, n = gt_correctness(seeds["x_left"][~only_left_half], seeds["x_right"][~only_left_half], d)
    assert n == (~only_left_half).sum() and share >= 0.95
    sl, sr = seeds["x_left"][only_left_half], seeds["x_right"][only_left_half]
    plain = propagate(left, right, sl, sr, F=seeds["F"], reseed_rounds=0)
    grown = propagate(left, right, sl, sr, F=seeds["F"])
    # without reseeding nothing crosses the flat band
    assert np.sum(plain.x_left[:, 0] > 150) == 0
    right_half = grown.x_left[:, 0] > 150
    assert right_half.sum() > 0.5 * 60 * 150                 # most of the far half's pixels
    # the seeds are the given ones and the reseeded ones (a point found twice counted once);
    # those beyond the band, where no seed was given, are correct against the truth
    assert len(sl) < np.sum(grown.parent < 0) <= len(sl) + grown.params["num_reseeded"]
    reseeds = (grown.parent < 0) & (grown.x_left[:, 0] >= 140)
    share, n = gt_correctness(grown.x_left[reseeds], grown.x_right[reseeds], d)
    assert n == reseeds.sum() and share >= 0.95
    share, _ = gt_correctness(grown.x_left[right_half], grown.x_right[right_half], d)
    assert share > 0.95
    # still one match per pixel in each image, seeds (of every pass) first, parents first
    assert len(np.unique(grown.x_left, axis=0)) == len(grown)
    assert len(np.unique(grown.x_right, axis=0)) == len(grown)
    assert np.all(grown.parent[:grown.num_seeds] == -1)
    child = np.arange(grown.num_seeds, len(grown))
    assert np.all((grown.parent[child] >= 0) & (grown.parent[child] < child))


def test_epipolar_seeds_are_distinct_and_left_right_consistent(slanted_pair):
    from canopy_stereo.features.quasi_dense import epipolar_seeds

    left, right, d = slanted_pair
    F = np.array([[0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])      # rectified pair: v' = v
    vv, uu = np.mgrid[20:160:10, 30:220:10]
    cand = np.column_stack([uu.ravel(), vv.ravel()])
    found = epipolar_seeds(left, right, F, cand, (-30, 0, -2, 2))
    assert len(found) > 0.8 * len(cand)
    share, _ = gt_correctness(found[:, :2], found[:, 2:4], d)
    assert share > 0.98
    assert np.all(found[:, 4] >= 0.9)
    # a flat image gives nothing, and a box that excludes the truth gives nothing right
    flat = np.full_like(left, 90)
    assert len(epipolar_seeds(flat, flat, F, cand, (-30, 0, -2, 2))) == 0
    wrong = epipolar_seeds(left, right, F, cand, (5, 30, -2, 2))
    assert len(wrong) < 0.05 * len(cand)
    with pytest.raises(CanopyStereoError):
        epipolar_seeds(left, right, F, cand, (-30, 0, -2, 2), half_window=0)


def test_resampling_places_cut_regions_at_the_inliers_centroid():
    from canopy_stereo.features.quasi_dense import Propagation

    # matches only on the left 3 columns of each 8x8 cell (a region cut by an edge)
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    keep = (u % 8) < 3
    xl = np.column_stack([u[keep], v[keep]]).astype(np.int32)
    xr = xl.copy()
    xr[:, 0] += 5
    prop = Propagation(xl, xr, np.ones(len(xl), np.float32), np.full(len(xl), -1), len(xl),
                       (64, 48), {})
    cl, cr, _ = resample(prop, anchor="centre")
    assert len(cl) == 0                                      # centre not surrounded
    cl, cr, _ = resample(prop, anchor="centroid")
    assert len(cl) == 0                                      # thin: refused by default
    cl, cr, support = resample(prop, anchor="centroid", thin_spread_px=0.0)
    assert len(cl) == 48                                     # every cell, one surface
    assert np.allclose(cl[:, 0] % 8, 1.0) and np.allclose(cl[:, 1] % 8, 3.5)
    assert np.allclose(cr, cl + [5, 0])
    with pytest.raises(CanopyStereoError, match="anchor"):
        resample(prop, anchor="middle")
    # the same strips beside a region matched with another displacement (an occlusion
    # edge) are refused; that full region is resampled at its cell centres
    a = (u % 16) < 3
    b = (u % 16) >= 8
    xl2 = np.column_stack([np.r_[u[a], u[b]], np.r_[v[a], v[b]]]).astype(np.int32)
    xr2 = xl2.copy()
    xr2[:len(u[a]), 0] += 5
    xr2[len(u[a]):, 0] -= 3
    prop2 = Propagation(xl2, xr2, np.ones(len(xl2), np.float32), np.full(len(xl2), -1),
                        len(xl2), (64, 48), {})
    cl2, cr2, _ = resample(prop2, anchor="centroid", thin_spread_px=0.0)
    cells = np.floor(cl2[:, 0] / 8).astype(int)
    assert len(cl2) == 4 * 6 and np.all(cells % 2 == 1)      # the 4 x 6 cells of region b, one each
    assert np.allclose(cl2 % 8, 3.5) and np.allclose(cr2, cl2 - [3, 0])


def test_aperture_coupling_measures_edges_along_the_epipolar_line():
    from canopy_stereo.features.quasi_dense import aperture_coupling

    rows = np.array([1.0, 0.0, 0.0])                   # rectified: epipolar lines = rows
    v, u = np.mgrid[0:60, 0:80].astype(np.float64)

    def edge(theta_deg):
        """Step edge making theta degrees with the image rows."""
        t = np.deg2rad(theta_deg)
        side = (u - 40.3) * np.sin(t) - (v - 30.3) * np.cos(t)
        return np.where(side > 0, 200.0, 50.0)

    def at_centre(img):
        return aperture_coupling(cv2.GaussianBlur(img, (0, 0), 2.0), 2, rows)[30, 40]

    assert at_centre(edge(90)) == pytest.approx(0.0, abs=1e-6)     # across the rows
    assert at_centre(edge(45)) == pytest.approx(1.0, rel=0.05)
    assert at_centre(edge(15)) == pytest.approx(1 / np.tan(np.deg2rad(15)), rel=0.1)
    texture = np.random.default_rng(3).uniform(0, 255, (60, 80))
    assert np.median(aperture_coupling(cv2.GaussianBlur(texture, (0, 0), 1.0), 2, rows)) < 0.5
    assert np.isinf(aperture_coupling(np.full((20, 20), 9.0), 2, rows)).all()


def test_interior_check_keeps_matches_off_the_band_smeared_past_a_depth_edge():
    from canopy_stereo.features.quasi_dense import Propagation

    # a foreground (u < 24, displacement +10) whose windows smeared its displacement 3 px
    # into the untextured background beside it (u 24..26): a thin band, one surface
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    keep = u < 27
    xl = np.column_stack([u[keep], v[keep]]).astype(np.int32)
    xr = xl.copy()
    xr[:, 0] += 10
    prop = Propagation(xl, xr, np.ones(len(xl), np.float32), np.full(len(xl), -1), len(xl),
                       (64, 48), {})
    kw = dict(anchor="centroid", thin_spread_px=0.0, min_spread_px=1.0, min_support=8,
              min_inlier_share=0.75)
    cl, cr, _ = resample(prop, interior_px=0, **kw)
    assert np.any(cl[:, 0] >= 24)                              # the band emits a match
    cl, cr, _ = resample(prop, interior_px=3, **kw)
    assert len(cl) == 3 * 6 and np.all(cl[:, 0] < 24)          # only the foreground's cells
    assert np.allclose(cr, cl + [10, 0])
    # the check runs along the epipolar lines: with vertical ones the band is interior
    cl, _, _ = resample(prop, interior_px=3, epipole=[0.0, 1.0, 0.0], **kw)
    assert np.any(cl[:, 0] >= 24)
    # the anchor mask restricts where a match may be placed
    mask = np.ones((48, 64), bool)
    mask[:, :8] = False
    cl, _, _ = resample(prop, interior_px=3, anchor_mask=mask, **kw)
    assert len(cl) == 2 * 6 and np.all(cl[:, 0] >= 8)
    with pytest.raises(CanopyStereoError, match="interior_shape"):
        resample(prop, interior_px=3, interior_shape="circle")
    with pytest.raises(CanopyStereoError, match="anchor_mask"):
        resample(prop, anchor_mask=np.ones((4, 4), bool))


def test_qdmatch_settings_are_one_frozen_dataclass(slanted_pair):
    """``QuasiDenseParams`` holds every qdmatch setting: frozen, replaced by name (an unknown
    name is one clear error), and ``params=`` gives the matches the same keywords give."""
    import dataclasses

    from canopy_stereo.features.quasi_dense import QuasiDenseParams, qdmatch
    from canopy_stereo.io.images import to_gray

    left, right = slanted_pair[:2]
    gl, gr = to_gray(left, "left"), to_gray(right, "right")
    base = QuasiDenseParams()
    assert len(dataclasses.fields(base)) == 32 and base.ratio == 0.8 and base.replace() is base
    with pytest.raises(dataclasses.FrozenInstanceError):
        base.ratio = 0.5  # type: ignore[misc]
    with pytest.raises(CanopyStereoError, match="unknown qdmatch parameter 'window'; known: anchor"):
        qdmatch(gl, gr, window=3)
    by_params = qdmatch(gl, gr, params=base.replace(cell_px=16, zncc_min=0.85))
    by_keywords = qdmatch(gl, gr, cell_px=16, zncc_min=0.85)
    np.testing.assert_array_equal(by_params.x_left, by_keywords.x_left)
    np.testing.assert_array_equal(by_params.x_right, by_keywords.x_right)
    assert by_params.num > 0
