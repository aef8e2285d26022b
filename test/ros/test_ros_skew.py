"""rectify_node's skew compensation: the core's function on every pair, reported on /diagnostics."""
import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.geometry.rectification import StereoRectifier, fusiello_rectify  # noqa: E402
from canopy_stereo.io.images import to_gray  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import wait_for  # noqa: E402
from canopy_stereo.ros.diagnostics import status_values  # noqa: E402
from canopy_stereo.ros.params import rig_parameter_overrides  # noqa: E402
from canopy_stereo.skew import SkewCompensator  # noqa: E402
from test.skew.test_skew_compensation import _texture, _view  # noqa: E402

pytestmark = pytest.mark.ros

T0 = 1_700_000_000_000_000_000
PERIOD_NS, SKEW_NS = 66_000_000, 10_000_000


def _moving_pairs(n=3):
    """A texture sliding 12 px per frame past the rig: (left, right, t_left, t_right), right 10 ms late."""
    tex = _texture(h=480, w=640, seed=7, margin=80)
    speed = 12.0 / PERIOD_NS
    return [(_view(tex, speed * k * PERIOD_NS, 0, h=480, w=640, margin=80),
             _view(tex, speed * (k * PERIOD_NS + SKEW_NS), 0, h=480, w=640, margin=80),
             T0 + k * PERIOD_NS, T0 + k * PERIOD_NS + SKEW_NS) for k in range(n)]


@pytest.mark.parametrize("enabled", [True, False])
def test_rectify_node_brings_each_right_image_to_the_left_instant(harness, paper_rig, enabled):
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    overrides = rig_parameter_overrides(paper_rig) + [Parameter("sync_slop", value=0.02),
                                                      Parameter("skew_compensation", value=enabled),
                                                      Parameter("diagnostic_period", value=0.0)]  # one window
    node = harness.add(RectifyNode(context=harness.ctx, namespace="/stereo", parameter_overrides=overrides,
                                   start_parameter_services=False))
    rect_r = harness.collect(Image, "right/image_rect")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    pairs = _moving_pairs()
    for left, right, tl, tr in pairs:
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=tl, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=tr, frame_id="right_camera"))
        n = len(rect_r)
        assert wait_for(lambda n=n: len(rect_r) > n, 20.0)  # in order: one pair at a time
    # the very shift batch and the core tests use, with the same defaults, composed into the
    # rectification of the grey right image; within a grey level of moving the raw image first
    core = SkewCompensator(enabled=enabled)
    rectifier = StereoRectifier(paper_rig, fusiello_rectify(paper_rig.P_left, paper_rig.P_right,
                                                            paper_rig.image_size))
    two_step = SkewCompensator(enabled=enabled)
    for msg, (left, right, tl, tr) in zip(rect_r, pairs):
        grey = to_gray(right)
        shift, _ = core.measure(grey, stamp_left_ns=tl, stamp_right_ns=tr)
        want = (rectifier.rectify_one(grey, "right") if shift is None
                else shift.apply(grey, coords=rectifier.coordinates("right")))
        got = convert.msg_to_image(msg)
        np.testing.assert_array_equal(got, want)
        moved_first = to_gray(rectifier.rectify(*two_step.compensate(left, right, stamp_left_ns=tl,
                                                                       stamp_right_ns=tr)[:2])[1])
        inner = (slice(40, -40), slice(60, -60))  # away from the borders the two-step warp replicates
        assert np.abs(got[inner].astype(float) - moved_first[inner]).mean() <= 1.0
        assert convert.stamp_to_ns(msg.header.stamp) == tl  # the pair's instant: the left image's
    values = status_values(node.diagnostics.status(reset=False))
    assert float(values["skew ms mean"]) == pytest.approx(10.0)
    if enabled:
        assert float(values["skew compensated % mean"]) == pytest.approx(200 / 3, abs=0.1)
        assert values["skew not compensated: first frame"] == "1"
        assert float(values["skew shift px mean"]) == pytest.approx(12.0 * 10 / 66, abs=0.3)
        assert float(values["skew compensation ms mean"]) > 0
        assert node.stats()["counts"]["pairs_skew_compensated"] == 2
    else:
        assert "skew compensated % mean" not in values
