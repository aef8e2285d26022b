"""Stamps that make no sense are named: zero stamps (restamped or dropped, a WARN on
/diagnostics either way), duplicated stamps (counted as duplicates, not as frames lost
upstream), stamps far from the receive time (a warning with the gap)."""
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import wait_for  # noqa: E402
from canopy_stereo.ros.stamps import StampCheck  # noqa: E402
from test.support.nodes import T0, TIMEOUT, node_kwargs, textured_pair  # noqa: E402

PERIOD_NS = 100_000_000


def test_stamp_check_verdicts():
    check = StampCheck(2, max_gap_s=0.5)
    assert check.check(0, 0, 123).stamp_ns == 123  # zero: the receive time
    assert "zero stamp" in check.check(0, 0, 124).warnings[0]
    assert check.check(1, T0, T0).stamp_ns == T0 and not check.check(1, T0 + 1, T0).warnings
    dup = check.check(1, T0 + 1, T0)
    assert dup.stamp_ns is None and dup.drop_reason.startswith("duplicate stamp")
    assert check.take_duplicates(1) == 1 and check.take_duplicates(1) == 0
    far = check.check(1, T0 + 2, T0 + 2 + 1_250_000_000)
    assert far.stamp_ns == T0 + 2 and "1.250 s behind the receive time" in far.warnings[0]
    dropping = StampCheck(1, zero_stamps="drop")
    assert dropping.check(0, 0, 5).stamp_ns is None
    one_frame = StampCheck(1)  # a looping one-frame source repeats one stamp: not duplicates
    assert all(one_frame.check(0, T0, T0 + k).stamp_ns == T0 for k in range(3))


def _rectify(harness, rig, **params):
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    node = harness.add(RectifyNode(**node_kwargs(harness, rig, diagnostic_period=0.3, **params)))
    out = harness.collect(Image, "left/image_rect_color")
    diagnostics = harness.collect(DiagnosticArray, "/diagnostics")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    return node, out, diagnostics, pl, pr


def _statuses(diagnostics, name="stereo/rectify_node: pipeline"):
    return [s for msg in list(diagnostics) for s in msg.status if s.name == name]


def test_zero_stamps_are_restamped_with_a_warn_on_diagnostics(harness, paper_rig):
    """A driver that never stamps: every pair still becomes rectified images, stamped with the
    receive time (not 0), and /diagnostics says WARN with the reason."""
    import time

    node, out, diagnostics, pl, pr = _rectify(harness, paper_rig)
    left, right = textured_pair(paper_rig)
    before = time.time_ns()
    for k in range(5):
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=0, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=0, frame_id="right_camera"))
        assert wait_for(lambda k=k: len(out) == k + 1, TIMEOUT)
        time.sleep(0.1)
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in out]
    assert all(s >= before for s in stamps) and len(set(stamps)) == 5
    assert wait_for(lambda: any(s.level == DiagnosticStatus.WARN and "zero stamp" in s.message
                                for s in _statuses(diagnostics)), TIMEOUT)
    warned = [s for s in _statuses(diagnostics) if "zero stamp" in s.message][0]
    assert any(kv.key.startswith("warning: left frame: zero stamp: restamped with the receive time")
               for kv in warned.values)
    assert sum(node.warnings.values()) == 10 and not node.drops


def test_zero_stamps_dropped_when_asked(harness, paper_rig):
    node, out, diagnostics, pl, pr = _rectify(harness, paper_rig, zero_stamps="drop")
    left, right = textured_pair(paper_rig)
    for _ in range(3):
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=0, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=0, frame_id="right_camera"))
    assert wait_for(lambda: sum(node.drops.values()) == 6, TIMEOUT)
    assert out == [] and all("zero stamp" in k for k in node.drops)
    assert wait_for(lambda: any(s.level == DiagnosticStatus.WARN and "zero stamp" in s.message
                                for s in _statuses(diagnostics)), TIMEOUT)


def test_duplicated_stamps_are_counted_as_duplicates_not_lost_frames(harness, paper_rig):
    """Frames 3 and 7 carry the stamp of the frame before them (the driver repeats stamps):
    two drops 'duplicate stamp', none 'missed ... lost upstream'; the other pairs are published."""
    from canopy_stereo.ros.nodes.rectify import MISSED_REASON

    node, out, diagnostics, pl, pr = _rectify(harness, paper_rig)
    left, right = textured_pair(paper_rig)
    stamps = [T0 + (k - 1 if k in (3, 7) else k) * PERIOD_NS for k in range(10)]
    for n, t in enumerate(stamps):
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 3_000_000, frame_id="right_camera"))
        assert wait_for(lambda n=n: len(out) + sum(node.drops.values()) // 2 == n + 1, TIMEOUT), node.drops
    drops = node.stats()["drops"]
    assert not any(MISSED_REASON in k for k in drops), drops
    assert sum(n for k, n in drops.items() if "duplicate stamp" in k) == 4, drops  # left and right
    assert len(out) == 8
    assert wait_for(lambda: any(kv.key.startswith("dropped: left frame: duplicate stamp")
                                for s in _statuses(diagnostics) for kv in s.values), TIMEOUT)


def test_a_stamp_far_from_the_receive_time_is_reported_with_the_gap(harness, paper_rig):
    import time

    node, out, diagnostics, pl, pr = _rectify(harness, paper_rig, max_stamp_gap=1.0)
    left, right = textured_pair(paper_rig)
    t = time.time_ns() - 5 * 10**9  # a driver whose clock is 5 s behind
    pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
    pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t, frame_id="right_camera"))
    assert wait_for(lambda: len(out) == 1, TIMEOUT)  # kept
    assert wait_for(lambda: any("s behind the receive time" in s.message and s.level == DiagnosticStatus.WARN
                                for s in _statuses(diagnostics)), TIMEOUT)
    gap = float(next(k for k in node.warnings).split("stamp ")[1].split(" s")[0])
    assert 5.0 <= gap < 6.5
