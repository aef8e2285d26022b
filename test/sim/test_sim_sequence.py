"""Field sequences of the simulator: a moving rig, wind, each camera's own clock and sensor, MJPEG."""
from dataclasses import replace

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.sim import CLEAN, rig_at_resolution
from canopy_stereo.sim.sequence import CaptureTiming, RigMotion, SequenceSpec, depth_accuracy, render_sequence


@pytest.fixture(scope="module")
def small_rig(paper_rig):
    return rig_at_resolution(paper_rig, 0.25)  # 160x120: quick renders


def _frames(rig, **kw):
    kw.setdefault("supersample", 1)
    return list(render_sequence(SequenceSpec(**kw), rig))


def test_capture_times_follow_each_camera_clock():
    t = CaptureTiming(fps=15.0, skew=0.008).times(4)
    assert np.allclose(t[:, 0], np.arange(4) / 15.0)
    assert np.allclose(t[:, 1] - t[:, 0], 0.008)
    jittered = CaptureTiming(fps=15.0, skew=0.008, jitter=0.002).times(200, seed=1)
    assert np.std(jittered[:, 1] - jittered[:, 0] - 0.008) == pytest.approx(0.002 * np.sqrt(2), rel=0.2)
    with pytest.raises(CanopyStereoError, match="shorter than a frame period"):
        CaptureTiming(fps=30.0, skew=0.040)
    with pytest.raises(CanopyStereoError, match="unknown motion direction"):
        RigMotion("sideways", 0.1)


@pytest.mark.slow
def test_rig_moving_toward_the_plants_sees_the_backdrop_come_closer(small_rig):
    frames = _frames(small_rig, frames=3, motion=RigMotion("toward", 0.5), timing=CaptureTiming(fps=15.0))
    # the rig passes its calibrated pose half-way: 33.3 mm before, at and after it
    distances = [f.truth["background"]["distance"] for f in frames]
    assert distances == pytest.approx([1000 + 500 / 15, 1000.0, 1000 - 500 / 15], abs=1e-6)
    assert frames[0].truth["rig_pose"]["d_mm"] == pytest.approx([0.0, 0.0, -500 / 15])


def test_rig_moving_along_the_baseline_skews_the_right_view(small_rig):
    """Right camera 8 ms late at 0.25 m/s along the baseline: it sees every point as if from
    2 mm further along, so the true right-view points are the left-instant points moved by 2 mm."""
    frames = _frames(small_rig, frames=1, motion=RigMotion("along", 0.25),
                     timing=CaptureTiming(fps=15.0, skew=0.008))
    f = frames[0]
    assert f.t_right - f.t_left == pytest.approx(0.008)
    assert f.truth["skew_ms"] == pytest.approx(8.0)
    still = _frames(small_rig, frames=1, timing=CaptureTiming(fps=15.0, skew=0.008))[0]
    # the backdrop's texture is fixed to it: the left view is the still one (rig at its pose at t = 0)
    assert np.array_equal(f.left, still.left)
    assert not np.array_equal(f.right, still.right)


@pytest.mark.slow
def test_wind_moves_leaves_faster_the_stronger_it_is(small_rig):
    speeds = {}
    for wind in (0.0, 1.0, 3.0):
        f = _frames(small_rig, frames=2, wind=wind, timing=CaptureTiming(fps=15.0))[1]
        speeds[wind] = f.truth["leaf_speed_mm_s"]["median"]
    assert speeds[0.0] == 0.0
    assert 0 < speeds[1.0] < speeds[3.0]
    assert speeds[3.0] / speeds[1.0] == pytest.approx(9.0, rel=0.5)  # about wind squared


def test_cameras_have_their_own_white_balance_and_mjpeg(small_rig):
    effects = replace(CLEAN, white_balance_right=(1.25, 1.0, 0.8))
    f = _frames(small_rig, frames=1, effects=effects, jpeg_quality=80)[0]
    assert f.jpeg_left is not None and f.jpeg_left[:2] == b"\xff\xd8"
    assert np.array_equal(cv2.imdecode(np.frombuffer(f.jpeg_right, np.uint8), cv2.IMREAD_COLOR), f.right)
    lossless = _frames(small_rig, frames=1, effects=effects)[0]
    assert lossless.jpeg_left is None
    assert 0 < np.mean(np.abs(lossless.left.astype(int) - f.left)) < 15  # JPEG at 80 on a 160x120 plant: lossy
    blue_red = [img[..., 0].mean() / img[..., 2].mean() for img in (lossless.left, lossless.right)]
    assert blue_red[1] < 0.9 * blue_red[0]  # the right camera renders warmer
    assert f.truth["jpeg_quality"] == 80
    assert f.truth["camera_effects"]["white_balance_right"] == [1.25, 1.0, 0.8] or \
        tuple(f.truth["camera_effects"]["white_balance_right"]) == (1.25, 1.0, 0.8)


def test_depth_accuracy_of_the_truth_itself_is_exact(small_rig):
    f = _frames(small_rig, frames=1)[0]
    err, density = depth_accuracy(f, f.xyz_left, small_rig)
    assert err == 0.0 and density == 1.0
    empty = np.full_like(f.xyz_left, np.nan)
    err, density = depth_accuracy(f, empty, small_rig)
    assert np.isnan(err) and density == 0.0
