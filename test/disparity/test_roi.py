"""Disparity only in the plant region of the previous masks (issue 28 item 1): the window, the
full-frame fallbacks, and the masked path against the full path on the plant pixels."""
import numpy as np
import pytest

from canopy_stereo.disparity import compute_disparity
from canopy_stereo.disparity.roi import (
    ALIGN,
    MAX_MASK_AGE,
    RoiPlanner,
    disparity_in_window,
    match_window,
    plant_box,
)
from canopy_stereo.errors import CanopyStereoError

SIZE = (640, 480)


def _mask(*boxes, size=SIZE):
    m = np.zeros(size[::-1], np.uint8)
    for x0, y0, x1, y1 in boxes:
        m[y0:y1, x0:x1] = 255
    return m


def test_plant_box_and_share():
    box, share = plant_box(_mask((100, 50, 200, 150), (300, 60, 310, 70)))
    assert box == (100, 50, 310, 150)
    assert share == pytest.approx((100 * 100 + 10 * 10) / (640 * 480))
    assert plant_box(_mask()) == (None, 0.0)
    with pytest.raises(CanopyStereoError, match="plant mask"):
        plant_box(np.zeros(5, np.uint8))


def test_window_covers_the_dilated_plant_and_every_column_its_search_needs():
    w = match_window((300, 200, 400, 300), image_size=SIZE, disp_min=20, disp_max=60, margin=16, max_share=1.0)
    # dilated and aligned outwards
    assert w.x0 <= 284 and w.y0 <= 184 and w.x1 >= 416 and w.y1 >= 316
    assert all(v % ALIGN == 0 for v in (w.y0, w.y1, w.x1, w.xa, w.ya, w.yb, w.xb))
    assert w.xa < w.x0 and w.ya < w.y0 and w.xb > w.x1 and w.yb > w.y1
    # right crop = left crop shifted by disp_min: each kept pixel u >= x0 finds u - d for every
    # d in [disp_min, disp_max] inside it
    assert w.shift == 20
    assert w.x0 - 60 >= w.xa - w.shift
    # a window larger than max_share of the frame: the full frame instead
    assert match_window((10, 10, 630, 470), image_size=SIZE, disp_min=0, disp_max=64) is None
    # near the left border: the crop cannot start before the image (nor the right crop)
    w = match_window((5, 100, 60, 200), image_size=SIZE, disp_min=10, disp_max=64, margin=8, max_share=1.0)
    assert w.xa - w.shift >= 0 and w.x0 >= w.xa


def test_disparity_in_window_is_invalid_outside_and_follows_the_search_shift():
    from canopy_stereo.sim.stereo_pair import synthetic_pair

    left, right, truth = synthetic_pair(320, 240, plane=(0.0, 0.0, 30.0), texture="blocks")
    w = match_window((120, 80, 220, 160), image_size=(320, 240), disp_min=20, disp_max=44, margin=8,
                     max_share=1.0)
    disp = disparity_in_window(left, right, w, matcher="elas", disp_min=20, disp_max=44)
    assert disp.shape == (240, 320)
    inside = np.zeros(disp.shape, bool)
    inside[w.y0:w.y1, w.x0:w.x1] = True
    assert np.all(disp[~inside] < 0)
    ok = inside & (disp >= 0)
    full = compute_disparity(left, right, disp_min=20, disp_max=44)
    assert ok.sum() >= 0.98 * (inside & (full >= 0)).sum()
    assert np.median(np.abs(disp[ok] - truth[ok])) < 0.5


def test_planner_falls_back_to_the_full_frame_on_start_cuts_new_plants_and_periodically():
    planner = RoiPlanner(margin=16, full_every=5, max_share=0.8)
    plan = lambda k: planner.plan(k, image_size=SIZE, disp_min=0, disp_max=64)  # noqa: E731
    window, reason = plan(0)
    assert window is None and reason == "no mask yet"
    plant = _mask((300, 200, 400, 300))
    planner.observe(0, plant)
    window, reason = plan(1)
    assert window is not None and reason == ""
    assert window.x0 <= 284 and window.x1 >= 416
    planner.observe(1, plant)
    assert plan(2)[0] is not None
    # a second plant enters the view (the area doubles): a cut, the full frame once
    planner.observe(2, _mask((300, 200, 400, 300), (60, 300, 160, 400)))
    window, reason = plan(3)
    assert window is None and "area jumped" in reason
    planner.observe(3, _mask((300, 200, 400, 300), (60, 300, 160, 400)))
    window, _ = plan(4)
    assert window is not None and window.x0 <= 44  # both plants inside
    # the plant grows past the window its frame was matched in (motion beyond the margin)
    planner.observe(4, _mask((300, 200, 400, 300), (60, 300, 160, 400), (window.x1 - 5, 250, window.x1 + 1, 255)))
    window, reason = plan(5)
    assert window is None and "border of the window" in reason
    # every full_every frames the full frame, whatever the masks say
    for k in range(6, 30):
        planner.observe(k - 1, _mask((300, 200, 400, 300), (60, 300, 160, 400)))
        window, reason = plan(k)
        if window is None:
            assert reason.startswith("periodic"), reason
            break
    else:
        pytest.fail("no periodic full frame")
    # the plant leaves (empty mask): full frames until a plant is seen again
    planner.observe(100, _mask())
    assert plan(101) == (None, "no plant in the last mask")
    assert plan(102) == (None, "no plant in the last mask")
    # masks stop arriving: the full frame after MAX_MASK_AGE frames
    planner.observe(200, plant)
    reasons = [plan(201 + k)[1] for k in range(MAX_MASK_AGE + 1)]
    assert reasons[0] == "" and reasons[-1].startswith("no new mask")
    with pytest.raises(CanopyStereoError):
        RoiPlanner(full_every=0)


@pytest.mark.slow
def test_masked_path_equals_the_full_path_on_the_plant_pixels(paper_rig):
    """Two potted plants side by side (pots, a table) seen from a rig moving along its baseline
    (8 mm/frame, 640x480),
    truth per frame. Frame k is matched in the window of frame k-1's plant mask (the true leaf
    mask, rectified) and in full. On frame k's plant pixels:

    * the same pixels get a disparity (density within 0.5 points): the window holds the plant
      with its margin, motion included;
    * the disparities agree: identical for most pixels and within 1 px for >= 99.5 % of them.
      ELAS is not bit-identical on a crop: its support points near the window's border, the
      Delaunay mesh over them and the gap interpolation along rows and columns see less of the
      image; the window is aligned to the support-candidate grid so the rest coincides;
    * the depth error against the truth is the same (median within 0.05 % of depth).
    """
    from canopy_stereo.geometry.rectification import cached_rectifier
    from canopy_stereo.geometry.triangulation import organized_from_disparity
    from canopy_stereo.io.images import to_gray
    from canopy_stereo.pipeline.reconstruct import disparity_range_for, rectify_rig
    from canopy_stereo.sim.sequence import CaptureTiming, RigMotion, SequenceSpec, depth_accuracy, render_sequence

    rig = paper_rig
    frames = list(render_sequence(SequenceSpec(scene="pots_side_by_side", frames=3, supersample=1,
                                               motion=RigMotion("along", 0.12), timing=CaptureTiming(fps=15.0)),
                                  rig))
    rect = rectify_rig(rig, "fusiello")
    rectifier = cached_rectifier(rig, rect)
    dmin, dmax = disparity_range_for(rig, rect)
    planner = RoiPlanner()
    previous = None
    for k, f in enumerate(frames):
        left, right = (to_gray(im) for im in rectifier.rectify(f.left, f.right))
        leaves = (f.leaf_ids_left > 0).astype(np.uint8) * 255
        plant = rectifier.rectify_one(leaves, "left") >= 128
        if previous is not None:
            planner.observe(k - 1, previous)
        window, reason = planner.plan(k, image_size=left.shape[::-1], disp_min=dmin, disp_max=dmax)
        previous = plant.astype(np.uint8) * 255
        if k == 0:
            assert window is None and reason == "no mask yet"
            continue
        assert window is not None, reason
        assert window.matched_share < 0.8
        full = compute_disparity(left, right, disp_min=dmin, disp_max=dmax)
        roi = disparity_in_window(left, right, window, matcher="elas", disp_min=dmin, disp_max=dmax)
        got_full, got_roi = plant & (full >= 0), plant & (roi >= 0)
        assert abs(got_full.sum() - got_roi.sum()) <= 0.005 * plant.sum()
        both = got_full & got_roi
        diff = np.abs(full[both] - roi[both])
        assert np.mean(diff == 0) > 0.8
        assert np.mean(diff <= 1.0) >= 0.995
        errors = []
        for disp in (full, roi):
            organized = organized_from_disparity(disp, rect, rig.P_left, rig.P_right, rig.image_size,
                                                 D_left=rig.D_left, distortion_model=rig.distortion_model)
            errors.append(depth_accuracy(f, organized, rig))
        (e_full, d_full), (e_roi, d_roi) = errors
        print(f"frame {k}: window {window.box}, matched {window.matched_share:.2f} of the frame; plant density "
              f"{d_full:.4f} / {d_roi:.4f}, identical {np.mean(diff == 0):.4f}, within 1 px {np.mean(diff <= 1):.4f}, "
              f"median depth error {e_full:.5f} / {e_roi:.5f}")
        assert e_roi == pytest.approx(e_full, abs=5e-4)
        assert d_roi == pytest.approx(d_full, abs=0.005)
