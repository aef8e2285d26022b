"""ELAS end to end: synthetic pairs with known disparity, bad input, determinism, registry."""
from __future__ import annotations

import warnings

import numba
import numpy as np
import pytest

from canopy_stereo.elas import ElasWarning, elas_disparity, elas_run, make_params
from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.sim.stereo_pair import plane_pair, shifted_pair

PRESETS = ("robotics", "middlebury")


def _share_within(disp, gt, margin, tol=0.5):
    """Share of ground-truth pixels away from the borders matched within ``tol``
    (invalid estimates count as misses)."""
    region = np.zeros(gt.shape, bool)
    region[margin:-margin, margin:-margin] = True
    region &= np.isfinite(gt)
    region[:, :int(np.nanmax(gt)) + margin] = False  # left band: no right partner
    ok = (disp >= 0) & (np.abs(disp - gt) <= tol)
    return ok[region].mean()


@pytest.fixture(scope="module")
def shifted():
    return shifted_pair(200, 150, shift=12.0, seed=1)


@pytest.fixture(scope="module")
def slanted():
    return plane_pair(200, 150, plane=(0.05, 0.03, 8.0), seed=2)


@pytest.mark.parametrize("preset", PRESETS)
def test_constant_shift_is_recovered(shifted, preset):
    left, right, gt = shifted
    dl, dr = elas_disparity(left, right, preset=preset, disp_max=63)
    assert dl.dtype == np.float32 and dl.shape == left.shape
    assert dr.dtype == np.float32 and dr.shape == left.shape
    assert _share_within(dl, gt, 10) >= 0.95
    # the right map holds the same disparity (u_left = u_right + d)
    ok_r = (dr[10:-10, 10:-30] >= 0) & (np.abs(dr[10:-10, 10:-30] - 12.0) <= 0.5)
    assert ok_r.mean() >= 0.95


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("subpixel", [False, True])
def test_slanted_plane_is_recovered(slanted, preset, subpixel):
    left, right, gt = slanted
    dl, _ = elas_disparity(left, right, preset=preset, disp_max=63, subpixel=subpixel)
    assert _share_within(dl, gt, 10) >= 0.95


def test_subpixel_refinement_lowers_the_error_on_a_slanted_plane(slanted):
    left, right, gt = slanted
    region = np.zeros(gt.shape, bool)
    region[10:-10, 30:-10] = True

    def epe(**kw):
        d, _ = elas_disparity(left, right, preset="middlebury", disp_max=63, **kw)
        return np.abs(d - gt)[region & (d >= 0)].mean()

    plain, refined = epe(), epe(subpixel=True)
    assert refined < 0.6 * plain
    assert refined < 0.15


def test_outputs_are_negative_one_where_invalid(shifted):
    left, right, _ = shifted
    dl, dr = elas_disparity(left, right, preset="robotics", disp_max=63)
    for d in (dl, dr):
        bad = d < 0
        assert bad.any()                     # borders outside the support hull
        assert np.all(d[bad] == -1.0)
        assert np.isfinite(d).all()


def test_bgr_input_equals_grey_input(shifted):
    import cv2

    left, right, _ = shifted
    grey = elas_disparity(left, right, disp_max=63)[0]
    bgr = elas_disparity(cv2.cvtColor(left, cv2.COLOR_GRAY2BGR),
                         cv2.cvtColor(right, cv2.COLOR_GRAY2BGR), disp_max=63)[0]
    assert np.array_equal(grey, bgr)


def test_right_map_can_be_skipped(shifted):
    left, right, _ = shifted
    full_l, _ = elas_disparity(left, right, preset="middlebury", disp_max=63)
    only_l, none = elas_disparity(left, right, preset="middlebury", disp_max=63, right_map=False)
    assert none is None
    assert np.array_equal(full_l, only_l)


def test_subsampling_gives_half_size_full_resolution_disparities(shifted):
    left, right, gt = shifted
    dl, dr = elas_disparity(left, right, disp_max=63, subsampling=True)
    assert dl.shape == (75, 100) and dr.shape == (75, 100)
    inner = dl[8:-8, 15:-8]
    assert ((inner >= 0) & (np.abs(inner - 12.0) <= 0.5)).mean() >= 0.95


@pytest.mark.parametrize("crop", [(150, 200), (149, 199)])
def test_the_matcher_spreads_subsampled_disparities_over_their_blocks(shifted, crop):
    """The registry's ``elas`` matcher returns a subsampled map at the input's size, each
    value of the half-size map over its 2x2 block (odd sizes: the last row/column cut)."""
    from canopy_stereo.elas.matcher import elas_matcher

    h, w = crop
    left, right = (np.ascontiguousarray(im[:h, :w]) for im in shifted[:2])
    half, _ = elas_disparity(left, right, disp_max=63, subsampling=True, right_map=False)
    full = elas_matcher(left, right, disp_max=63, subsampling=True)
    assert full.shape == (h, w) and full.dtype == np.float32
    rows, cols = np.arange(h) // 2, np.arange(w) // 2
    assert np.array_equal(full, half[rows[:, None], cols[None, :]])
    assert (half >= 0).mean() > 0.5


def test_every_reference_parameter_is_a_keyword(shifted):
    left, right, _ = shifted
    names = ["disp_min", "disp_max", "support_threshold", "support_texture", "candidate_stepsize",
             "incon_window_size", "incon_threshold", "incon_min_support", "add_corners",
             "grid_size", "beta", "gamma", "sigma", "sradius", "match_texture", "lr_threshold",
             "speckle_sim_threshold", "speckle_size", "ipol_gap_width", "filter_median",
             "filter_adaptive_mean", "postprocess_only_left", "subsampling"]
    p = make_params("robotics")
    for n in names:
        assert hasattr(p, n), n
    # the presets differ as in the reference table
    m = make_params("middlebury")
    assert (m.support_threshold, m.add_corners, m.gamma, m.sradius, m.match_texture,
            m.ipol_gap_width, m.filter_median, m.filter_adaptive_mean,
            m.postprocess_only_left) == (0.95, True, 5.0, 3.0, 0, 5000, True, False, False)
    # a changed parameter changes the result: no support points with an impossible texture
    with pytest.warns(ElasWarning):
        dl, _ = elas_disparity(left[:, :100], right[:, :100], disp_max=40, support_texture=10**6)
    assert (dl < 0).all()


def test_identical_across_runs_and_thread_counts(slanted):
    left, right, _ = slanted
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = elas_disparity(left, right, preset="middlebury", disp_max=63, subpixel=True)
        again = elas_disparity(left, right, preset="middlebury", disp_max=63, subpixel=True)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = elas_disparity(left, right, preset="middlebury", disp_max=63, subpixel=True)
    finally:
        numba.set_num_threads(before)
    for a, b in ((one, again), (one, two)):
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_registered_as_matcher_elas(shifted):
    from canopy_stereo.disparity import available_matchers, compute_disparity

    left, right, gt = shifted
    assert "elas" in available_matchers()
    d = compute_disparity(left, right, matcher="elas", disp_min=0, disp_max=63)
    assert np.array_equal(d, elas_disparity(left, right, disp_max=63)[0])
    d = compute_disparity(left, right, matcher="elas", disp_max=63, preset="middlebury",
                          subsampling=True)
    assert d.shape == left.shape
    assert _share_within(d, gt, 12) >= 0.95


def test_timings_and_support_are_reported(shifted):
    left, right, _ = shifted
    res = elas_run(left, right, make_params("robotics", disp_max=63))
    for stage in ("descriptor", "support", "delaunay", "grid", "matching", "lr_check"):
        assert stage in res.timings
    assert len(res.support) > 20
    # where the true disparity is inside the searchable range (u - d - 2 >= 3) it is found
    searchable = res.support[:, 0] - 12 >= 5
    assert searchable.sum() > 20 and np.all(res.support[searchable, 2] == 12)


# ---------------------------------------------------------------- bad input
def test_different_sizes_raise(shifted):
    left, right, _ = shifted
    with pytest.raises(ImageError, match="sizes differ"):
        elas_disparity(left, right[:, :-1])


@pytest.mark.parametrize("shape", [(0, 0), (0, 10), (1, 1), (1, 50), (8, 8)])
def test_empty_or_tiny_images_raise(shape):
    img = np.zeros(shape, np.uint8)
    with pytest.raises(ImageError):
        elas_disparity(img, img)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint16, np.int32])
def test_non_uint8_images_raise(shifted, dtype):
    left, right, _ = shifted
    with pytest.raises(ImageError, match="uint8"):
        elas_disparity(left.astype(dtype), right.astype(dtype))


def test_wrong_channel_count_raises(shifted):
    left, _, _ = shifted
    two = np.dstack([left, left])
    with pytest.raises(ImageError):
        elas_disparity(two, two)


def test_untextured_images_give_all_invalid_and_a_warning():
    flat = np.full((60, 80), 128, np.uint8)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        dl, dr = elas_disparity(flat, flat)
    assert any(issubclass(w.category, ElasWarning) for w in caught)
    assert dl.shape == (60, 80) and np.all(dl == -1.0) and np.all(dr == -1.0)


@pytest.mark.parametrize("kw, match", [
    ({"disp_min": 20, "disp_max": 10}, "disp_max"),
    ({"disp_min": -1}, "disp_min"),
    ({"disp_min": 0, "disp_max": 5}, "at least 11"),
    ({"support_threshold": 1.5}, "support_threshold"),
    ({"bogus": 1}, "unknown ELAS parameter"),
])
def test_bad_parameters_raise(shifted, kw, match):
    left, right, _ = shifted
    with pytest.raises(CanopyStereoError, match=match):
        elas_disparity(left, right, **kw)


def test_unknown_preset_raises(shifted):
    left, right, _ = shifted
    with pytest.raises(CanopyStereoError, match="preset"):
        elas_disparity(left, right, preset="fastest")
