"""Every entry point calls the one skew compensation: batch here (rectify_node, and so ``run``:
test/ros/test_ros_skew.py), with the same defaults; and ``run`` on a moving-rig bag gets depth right."""
import numpy as np
import pytest

from canopy_stereo.skew import SkewCompensator
from test.skew.test_skew_compensation import _texture, _view

PERIOD_NS, SKEW_NS, T0 = 66_000_000, 12_000_000, 1_704_067_200_000_000_000


@pytest.fixture(scope="module")
def small_rig(paper_rig):
    from canopy_stereo.sim import rig_at_resolution

    return rig_at_resolution(paper_rig, 0.5)  # 320x240


@pytest.fixture(scope="module")
def moving_bag(tmp_path_factory, small_rig):
    """Four raw pairs of a texture sliding 10 px per frame, the right camera 12 ms late."""
    pytest.importorskip("rclpy")
    from canopy_stereo.ros.bundled import write_stereo_bag

    tex = _texture(seed=11)
    speed = 10.0 / PERIOD_NS
    frames = [(_view(tex, speed * k * PERIOD_NS, 0), _view(tex, speed * (k * PERIOD_NS + SKEW_NS), 0),
               T0 + k * PERIOD_NS, T0 + k * PERIOD_NS + SKEW_NS) for k in range(4)]
    path = write_stereo_bag(tmp_path_factory.mktemp("skew") / "moving.mcap", frames, rig=small_rig)
    return path, frames


@pytest.mark.parametrize("enabled, max_frames", [(True, 0), (False, 0), (True, 2)])
def test_batch_measures_the_pairs_the_compensation_gives(monkeypatch, moving_bag, enabled, max_frames):
    from canopy_stereo.batch import work

    path, frames = moving_bag
    seen = []

    def fake_measure(left, right, rig, **kw):
        seen.append((left, right))
        return {1: {name: 1.0 for name in work.TRAITS}}

    monkeypatch.setattr(work, "measure_frame_plants", fake_measure)
    rows = work.process_bag(str(path), work.BatchOptions(skew_compensation=enabled, max_frames=max_frames,
                                                         sync_slop_s=0.03))
    keep = sorted(work._spread(len(frames), max_frames))
    assert rows[0]["frames"] == len(keep) == len(seen)
    core = SkewCompensator(enabled=enabled)
    want = [core.compensate(left, right, stamp_left_ns=tl, stamp_right_ns=tr)[:2] for left, right, tl, tr in frames]
    for (got_l, got_r), k in zip(seen, keep):
        np.testing.assert_array_equal(got_l, want[k][0])
        np.testing.assert_array_equal(got_r, want[k][1])
    if enabled:  # the measured right images did move (all but the bag's first frame)
        assert any(not np.array_equal(got_r, frames[k][1]) for (_, got_r), k in zip(seen, keep))


@pytest.mark.slow
@pytest.mark.ros
def test_run_on_a_moving_rig_bag_gets_depth_right(tmp_path, cli, paper_rig):
    """``run`` on a simulated robot bag (MJPEG at quality 90, CompressedImage only) of a rig moving
    along its baseline at 0.25 m/s with the right camera 8 ms late: clouds within 1 % of the truth
    depth; 6 % off with --no-skew-compensation."""
    pytest.importorskip("rclpy")

    from canopy_stereo.bag import BagReader
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros import convert
    from canopy_stereo.ros.bundled import bundled_rig, read_truth_depths, relative_depth_errors

    bag = tmp_path / "moving.mcap"
    rig_file = bundled_rig("croton")  # the paper rig with the croton's disparity range
    code, out, err = cli("simulate", "croton", "-o", str(tmp_path / "frames"), "--rig", str(rig_file),
                         "--frames", "3", "--motion", "along", "--speed", "0.25", "--skew", "8", "--wind", "0",
                         "--jpeg-quality", "90", "--bag", str(bag), "--compressed")
    assert code == 0, err
    rig = load_rig(rig_file)
    truth = read_truth_depths(bag)
    medians = {}
    for flag in ([], ["--no-skew-compensation"]):
        rec = tmp_path / f"out{len(flag)}.mcap"
        code, out, err = cli("run", "--bag", str(bag), "--rig", str(rig_file), "--rate", "0", "--no-segment",
                             "--record", str(rec), *flag)
        assert code == 0, err
        clouds = {convert.stamp_to_ns(m.header.stamp): m for _, m in BagReader(rec).read("/stereo/points2")}
        stamps = sorted(truth)[1:]  # the first frame has no previous one
        assert set(stamps) <= set(clouds)
        medians[bool(flag)] = [float(np.median(relative_depth_errors(convert.cloud2_to_points(clouds[s])[0],
                                                                     rig, truth[s]))) for s in stamps]
    assert max(medians[False]) <= 0.01, medians
    assert min(medians[True]) >= 0.05, medians
