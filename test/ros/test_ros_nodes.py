"""The nodes, one at a time, in-process on a private DDS domain (numbers against the core)."""
import threading
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.geometry.camera import point_depth  # noqa: E402
from canopy_stereo.geometry.rectification import StereoRectifier, fusiello_rectify  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import wait_for  # noqa: E402
from test.support.nodes import (  # noqa: E402
    T0,
    TIMEOUT,
    geometry_publisher,
    node_kwargs,
    publish_rect_infos,
    rect_info_publishers,
    textured_pair,
)

pytestmark = pytest.mark.ros

# --------------------------------------------------------------------------- rectify_node


def test_rectify_node_pairs_by_approximate_time_and_publishes_ros_camera_info(harness, paper_rig):
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    # three pairs at once: all wait (one newest pair waits by default)
    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, sync_slop=0.01, waiting_pairs=3)))
    rect_l = harness.collect(Image, "left/image_rect")
    rect_r = harness.collect(Image, "right/image_rect")
    color = harness.collect(Image, "left/image_rect_color")
    info_l = harness.collect(CameraInfo, "left/image_rect/camera_info")
    info_r = harness.collect(CameraInfo, "right/image_rect/camera_info")
    driver_info = harness.collect(CameraInfo, "left/camera_info")  # the raw camera's: not rectify_node's
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    left, right = textured_pair(paper_rig)
    for k in range(3):
        t = T0 + k * 66_000_000
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 7_000_000,
                                        frame_id="right_camera"))  # 7 ms late
    assert wait_for(lambda: len(info_r) == 3 and len(rect_r) == 3 and len(color) == 3, TIMEOUT)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    rectifier = StereoRectifier(paper_rig, rect)
    want_l, want_r = rectifier.rectify(left, right)
    np.testing.assert_array_equal(convert.msg_to_image(color[0]), want_l)
    np.testing.assert_array_equal(convert.msg_to_image(rect_l[0]), cv2.cvtColor(want_l, cv2.COLOR_BGR2GRAY))
    # the right image only goes out grey: converted before the remap (one channel to resample),
    # within a grey level of converting after it
    got_r = convert.msg_to_image(rect_r[0])
    np.testing.assert_array_equal(got_r, rectifier.rectify_one(cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), "right"))
    assert np.abs(got_r.astype(int) - cv2.cvtColor(want_r, cv2.COLOR_BGR2GRAY)).max() <= 1
    assert rect_l[0].encoding == "mono8" and color[0].encoding == "bgr8"
    # one shared stamp per pair: the left frame's
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in rect_r]
    assert stamps == [T0 + k * 66_000_000 for k in range(3)]
    assert [convert.stamp_to_ns(m.header.stamp) for m in info_l] == stamps
    PL, PR = np.reshape(info_l[0].p, (3, 4)), np.reshape(info_r[0].p, (3, 4))
    f = rect.focal_length
    assert PL[0, 0] == pytest.approx(f) and PL[0, 3] == 0
    assert PR[0, 3] == pytest.approx(-f * paper_rig.baseline * 1e-3)  # -fx * baseline [m]
    assert -PR[0, 3] / PR[0, 0] == pytest.approx(0.0296, abs=1e-4)
    assert PL[0, 2] - PR[0, 2] == pytest.approx(rect.doffs) == 0.0  # one principal point
    assert (info_l[0].width, info_l[0].height) == (640, 480)
    assert info_l[0].header.frame_id == color[0].header.frame_id == "left_camera_rect_optical_frame"
    # one frame for the pair (image_geometry's StereoCameraModel asserts it): the left one
    assert info_r[0].header.frame_id == rect_r[0].header.frame_id == "left_camera_rect_optical_frame"
    assert driver_info == []
    assert node.stats()["drops"] == {}


def test_rectify_node_rectifies_the_newest_pairs_when_frames_come_faster(harness, paper_rig):
    """A burst of pairs faster than the node rectifies: the newest pair is always rectified,
    the ones overtaken while it worked are dropped as superseded (none processed late, none
    lost without a count), and the outputs leave in stamp order."""
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, sync_slop=0.01)))
    color = harness.collect(Image, "left/image_rect_color")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    left, right = textured_pair(paper_rig)
    stamps = [T0 + k * 33_000_000 for k in range(8)]
    for t in stamps:
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 4_000_000, frame_id="right_camera"))
    reason = "camera pair: superseded by newer ones while the node was busy"

    def settled():  # every complete pair rectified or counted as superseded
        stats = node.stats()
        return (stats["counts"].get("pairs_complete", 0) > 0 and stats["counts"].get("pairs_published", 0)
                + stats["drops"].get(reason, 0) == stats["counts"]["pairs_complete"])

    assert wait_for(settled, TIMEOUT), node.stats()
    time.sleep(0.3)
    assert settled(), node.stats()
    out = [convert.stamp_to_ns(m.header.stamp) for m in color]
    assert len(out) == node.stats()["counts"]["pairs_published"]
    assert out == sorted(out) and set(out) <= set(stamps)
    assert node.stats()["drops"].get(reason, 0) >= 1  # 8 pairs at once: some were overtaken


@pytest.mark.parametrize("matcher_reads", [True, False], ids=["matcher-reads", "nobody-reads-mono"])
def test_rectify_node_rectifies_only_what_the_matcher_can_take(harness, paper_rig, matcher_reads):
    """follow_matcher: while the matcher (``disparity/matching``) has not taken the last pair
    published, pairs that come are not rectified; the newest is, once it is taken or after
    MATCHER_WAIT_S; the ones in between are dropped as superseded. A pair whose mono images
    went to nobody (the matcher's readers not matched yet) is not waited for."""
    from std_msgs.msg import Header

    from canopy_stereo.ros.nodes.rectify import MATCHING_TOPIC, RectifyNode

    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, sync_slop=0.01)))
    color = harness.collect(Image, "left/image_rect_color")
    if matcher_reads:
        harness.collect(Image, "left/image_rect"), harness.collect(Image, "right/image_rect")
        assert wait_for(lambda: node.pub_left.get_subscription_count() and node.pub_right.get_subscription_count(),
                        TIMEOUT)
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    matching = harness.publisher(Header, MATCHING_TOPIC)
    harness.connect(pl, pr)
    assert wait_for(lambda: node.sub_matching.get_publisher_count() == 1, TIMEOUT)
    left, right = textured_pair(paper_rig)

    def send(t):
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 4_000_000, frame_id="right_camera"))

    a, b, c, d = (T0 + k * 33_000_000 for k in range(4))
    send(a)
    assert wait_for(lambda: len(color) == 1, TIMEOUT)
    send(b)  # a is not taken: b waits, c comes and is the newest
    if not matcher_reads:  # a went to nobody: b goes at once
        assert wait_for(lambda: len(color) == 2, TIMEOUT)
    send(c)
    assert wait_for(lambda: len(color) == 2 + (not matcher_reads), TIMEOUT)
    matching.publish(convert.make_header(c, "left_camera_rect_optical_frame"))
    send(d)  # c was taken: d goes at once
    assert wait_for(lambda: len(color) == 3 + (not matcher_reads), TIMEOUT)
    out = [convert.stamp_to_ns(m.header.stamp) for m in color]
    if matcher_reads:
        assert out == [a, c, d]
        assert node.stats()["drops"] == {"camera pair: superseded by newer ones while the node was busy": 1}
        # d is never taken (a matcher warming up, or a looping bag's repeated frame): e waits, goes,
        # and no pair waits again until the matcher takes one
        e = T0 + 4 * 33_000_000
        send(e)
        assert wait_for(lambda: len(color) == 4 and node._matcher_silent, TIMEOUT)
        matching.publish(convert.make_header(e, "left_camera_rect_optical_frame"))
        assert wait_for(lambda: not node._matcher_silent, TIMEOUT)
    else:
        assert out == [a, b, c, d] and node.stats()["drops"] == {}
        values = {kv.key for kv in node.diagnostics.status(reset=False).values}
        assert "matcher wait ms max" not in values  # no pair waited for a take that cannot come


def test_rectify_node_starts_a_pair_just_in_time_for_a_slow_matcher():
    """matcher_start_delay against a model of the graph: a matcher busy ``match`` s per pair,
    this node ``work`` s per pair, ``transport`` s between them. The pair is started
    match - work - margin after the take (frames that much fresher than at the take) and
    waits about the margin in the matcher's queue; a transport longer than the margin leaves
    the matcher idle that much longer per pair, a constant, never growing (the match time is
    the matcher's own, not the take interval a late start lengthens)."""
    from canopy_stereo.ros.nodes.rectify import START_MARGIN_S, matcher_start_delay

    assert matcher_start_delay(since_take_s=0.0, match_s=0.09, work_s=0.04) == pytest.approx(0.03)
    assert matcher_start_delay(since_take_s=0.05, match_s=0.09, work_s=0.04) == 0.0

    def intervals(match, work, transport, pairs=20):
        take, out = 0.0, []
        for _ in range(pairs):
            start = take + matcher_start_delay(since_take_s=0.0, match_s=match, work_s=work)
            arrival = start + work + transport
            nxt = max(take + match, arrival)  # the matcher is free, and the pair is there
            out.append((nxt - take, nxt - arrival))  # take interval, the pair's wait in the queue
            take = nxt
        return out

    for interval, wait in intervals(match=0.09, work=0.04, transport=0.005):
        assert interval == pytest.approx(0.09) and wait == pytest.approx(START_MARGIN_S - 0.005)
    late = intervals(match=0.09, work=0.04, transport=0.03)
    assert [i for i, _ in late] == pytest.approx([0.1] * 20)  # 10 ms idle per pair, not growing


@pytest.mark.slow
def test_rectify_node_starts_pairs_late_for_a_slow_matcher(harness, paper_rig):
    """In the node: a matcher busy 0.25 s per pair (``disparity/matching`` at each take,
    ``disparity/matched`` when done) and frames at 30 Hz. Once the take intervals and match
    times are known, the node waits after each take (counted, and ``start delay ms`` on
    /diagnostics) and
    publishes the next pair shortly before the matcher is free (0.23 s after the take), not
    its own time per pair after the take."""
    from std_msgs.msg import Header

    from canopy_stereo.ros.nodes.rectify import MATCHED_TOPIC, MATCHING_TOPIC, RectifyNode
    from canopy_stereo.ros.qos import recording_qos

    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, sync_slop=0.01)))
    arrivals = []  # (monotonic s, header) of each rectified pair
    harness.collect(Image, "left/image_rect")
    harness.helper.create_subscription(Image, "right/image_rect",
                                       lambda m: arrivals.append((time.monotonic(), m.header)), recording_qos())
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    taking, done = harness.publisher(Header, MATCHING_TOPIC), harness.publisher(Header, MATCHED_TOPIC)
    harness.connect(pl, pr)
    assert wait_for(lambda: node.sub_matching.get_publisher_count() == 1 and node.sub_matched.get_publisher_count()
                    == 1 and node.pub_right.get_subscription_count() == 1, TIMEOUT)
    left, right = textured_pair(paper_rig)
    ml = convert.image_to_msg(left, "bgr8", stamp_ns=T0, frame_id="left_camera")
    mr = convert.image_to_msg(right, "bgr8", stamp_ns=T0, frame_id="right_camera")
    stop = threading.Event()

    def camera():  # 30 frames/s
        k, t0 = 0, time.monotonic()
        while not stop.is_set():
            ml.header.stamp.sec, ml.header.stamp.nanosec = divmod(T0 + k * 33_333_333, 10**9)
            mr.header.stamp.sec, mr.header.stamp.nanosec = divmod(T0 + k * 33_333_333 + 4_000_000, 10**9)
            pl.publish(ml)
            pr.publish(mr)
            k += 1
            time.sleep(max(0.0, t0 + k / 30 - time.monotonic()))

    gaps = []  # s from a take to the arrival of the next pair
    thread = threading.Thread(target=camera, daemon=True)
    thread.start()
    try:
        takes, deadline = 0, time.monotonic() + 20.0
        while len(gaps) < 8 and time.monotonic() < deadline:
            n = len(arrivals)
            if n == 0:
                time.sleep(0.002)
                continue
            header = arrivals[-1][1]
            taking.publish(header)  # the matcher takes the newest pair and is busy 0.25 s
            took, takes = time.monotonic(), takes + 1
            time.sleep(0.25)
            done.publish(header)
            while len(arrivals) == n and time.monotonic() < deadline:
                time.sleep(0.002)
            if takes > 12 and len(arrivals) > n:  # the take intervals and match times known
                gaps.append(arrivals[n][0] - took)
    finally:
        stop.set()
        thread.join(5)
    assert len(gaps) == 8, (gaps, node.stats())
    assert node.stats()["counts"].get("pairs_started_just_in_time", 0) >= 8
    assert 0.24 <= np.median(node._match_times) < 0.5  # the matcher's time (its next take may come first)
    assert np.median(gaps) >= 0.15, gaps  # 0.23 s planned; the node's own time per pair is ~0.02 s


def test_rectify_node_drops_bad_input_and_keeps_running(harness, paper_rig):
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, sync_slop=0.005)))
    out = harness.collect(Image, "left/image_rect_color")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    left, right = textured_pair(paper_rig)
    # 1: wrong encoding (a depth image) on the left
    pl.publish(convert.image_to_msg(np.ones((480, 640), np.float32), "32FC1", stamp_ns=T0))
    pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=T0))
    # 2: wrong size pair
    pl.publish(convert.image_to_msg(left[:240, :320].copy(), "bgr8", stamp_ns=T0 + 100_000_000))
    pr.publish(convert.image_to_msg(right[:240, :320].copy(), "bgr8", stamp_ns=T0 + 100_000_000))
    # 3: an unpaired left frame (its right partner lost), then a good pair
    pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=T0 + 200_000_000))
    pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=T0 + 300_000_000))
    pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=T0 + 301_000_000))
    assert wait_for(lambda: len(out) == 1, TIMEOUT)
    time.sleep(0.3)
    assert len(out) == 1 and convert.stamp_to_ns(out[0].header.stamp) == T0 + 300_000_000
    drops = node.stats()["drops"]
    text = " | ".join(drops)
    assert "'32FC1' not accepted" in text
    assert "320x240 but 640x480 is expected" in text
    assert "unpaired" in text or "no partner" in text
    assert sum(drops.values()) == 5  # 32FC1 left, its right, two small frames, the orphan left


def test_rectify_node_counts_frames_it_never_received(harness, paper_rig):
    """Left stamps at 10 Hz with frames 4, 5, 6 and 9 missing: 4 drops 'missed', in the
    node's counters and on /diagnostics; the pairs that came are all published."""
    from canopy_stereo.ros.nodes.rectify import MISSED_REASON, RectifyNode

    # diagnostic_period 0: one statistics window for the whole test (no timer resetting it midway)
    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, diagnostic_period=0.0)))
    out = harness.collect(Image, "left/image_rect_color")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    harness.connect(pl, pr)
    left, right = textured_pair(paper_rig)
    sent = [k for k in range(12) if k not in (4, 5, 6, 9)]
    for k in sent:
        t = T0 + k * 100_000_000
        pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera"))
        pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 3_000_000, frame_id="right_camera"))
        assert wait_for(lambda k=k: len(out) == sent.index(k) + 1, TIMEOUT)
    assert node.stats()["drops"] == {f"left frame: {MISSED_REASON}": 4}
    values = {kv.key: kv.value for kv in node.diagnostics.status().values}
    assert values[f"dropped: left frame: {MISSED_REASON}"] == "4"


# --------------------------------------------------------------------------- disparity_node


def test_disparity_node_fields_match_the_rig(harness, paper_rig):
    from std_msgs.msg import Header

    from canopy_stereo.ros.nodes.disparity import DisparityNode
    from canopy_stereo.ros.nodes.rectify import MATCHED_TOPIC, MATCHING_TOPIC

    node = harness.add(DisparityNode(**node_kwargs(harness, paper_rig, matcher="sgbm",
                                                   disp_min=16, disp_max=48)))
    out = harness.collect(DisparityImage, "disparity")
    pacing = harness.collect(Header, MATCHING_TOPIC), harness.collect(Header, MATCHED_TOPIC)
    pl, pr = harness.publisher(Image, "left/image_rect"), harness.publisher(Image, "right/image_rect")
    il, ir = rect_info_publishers(harness)
    harness.connect(pl, pr, il, ir)
    shift = 30
    left, right = textured_pair(paper_rig, shift)
    gl, gr = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
    pl.publish(convert.image_to_msg(gl, "mono8", stamp_ns=T0, frame_id="rect"))
    pr.publish(convert.image_to_msg(gr, "mono8", stamp_ns=T0, frame_id="rect"))
    time.sleep(0.1)
    assert out == []  # no camera_info yet: nothing to tell f and t
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    publish_rect_infos(il, ir, paper_rig, rect, T0)
    assert wait_for(lambda: len(out) == 1, TIMEOUT)
    msg = out[0]
    assert msg.f == pytest.approx(rect.focal_length, rel=1e-6)
    assert msg.t == pytest.approx(paper_rig.baseline * 1e-3, rel=1e-6)  # metres
    assert msg.min_disparity == pytest.approx(16 - rect.doffs, abs=1e-4)
    assert msg.max_disparity == pytest.approx(48 - rect.doffs, abs=1e-4)
    assert msg.delta_d == pytest.approx(1 / 16)
    assert msg.image.encoding == "32FC1" and (msg.image.width, msg.image.height) == (640, 480)
    raw = convert.msg_to_image(msg.image)
    valid = raw >= msg.min_disparity
    assert np.all(raw[~valid] < msg.min_disparity)
    # the textured pair is a pure shift: every matched pixel has d = shift (message: shift - doffs)
    assert valid.mean() > 0.6
    assert np.median(raw[valid]) == pytest.approx(shift - rect.doffs, abs=0.1)
    x, y, w, h = (msg.valid_window.x_offset, msg.valid_window.y_offset, msg.valid_window.width,
                  msg.valid_window.height)
    rows, cols = np.nonzero(valid)
    assert (x, y, x + w - 1, y + h - 1) == (cols.min(), rows.min(), cols.max(), rows.max())
    assert convert.stamp_to_ns(msg.header.stamp) == T0 and msg.header.frame_id == "rect"
    assert node.stats()["counts"]["disparities_published"] == 1
    # the pacing stamps of rectify_node's follow_matcher: the pair taken, then done with
    assert wait_for(lambda: all(pacing), TIMEOUT)
    assert [[(convert.stamp_to_ns(h.stamp), h.frame_id) for h in got] for got in pacing] == [[(T0, "rect")]] * 2


def test_disparity_node_matches_a_looping_bag_whose_images_start_after_a_wrap(harness, paper_rig):
    """A looping bag at start-up: rectify_node's camera_infos reach disparity_node before its
    images (published once the subscription is matched) and wrap around; then the same frame
    comes again and again (rectify_node's follow_matcher, while nothing is taken yet). The
    images belong with the infos of the wrapped time line: matched at once."""
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    node = harness.add(DisparityNode(**node_kwargs(harness, paper_rig, matcher="sgbm", disp_min=16, disp_max=48)))
    out = harness.collect(DisparityImage, "disparity")
    pl, pr = harness.publisher(Image, "left/image_rect"), harness.publisher(Image, "right/image_rect")
    il, ir = rect_info_publishers(harness)
    harness.connect(pl, pr, il, ir)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    frame = T0 + 100_000_000
    for stamp in (T0 + 200_000_000, T0 + 304_000_000, frame):  # the infos wrap around
        publish_rect_infos(il, ir, paper_rig, rect, stamp)
    assert wait_for(lambda: node.stats()["counts"].get("right_camera_info_received") == 3, TIMEOUT)
    gl, gr = (cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in textured_pair(paper_rig, 30))
    for k in range(3):  # the same frame on every pass
        if k:
            publish_rect_infos(il, ir, paper_rig, rect, frame)
        pl.publish(convert.image_to_msg(gl, "mono8", stamp_ns=frame, frame_id="rect"))
        pr.publish(convert.image_to_msg(gr, "mono8", stamp_ns=frame, frame_id="rect"))
        assert wait_for(lambda n=k + 1: len(out) == n, TIMEOUT), node.stats()["drops"]
    assert {convert.stamp_to_ns(m.header.stamp) for m in out} == {frame}


def test_disparity_node_parameters_change_at_run_time_and_are_validated(harness, paper_rig):
    pytest.importorskip("canopy_stereo.elas.params")
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    node = harness.add(DisparityNode(**node_kwargs(harness, paper_rig, matcher="sgbm")))
    assert node.config["matcher"] == "sgbm"
    ok = node.set_parameters([Parameter("disp_max", value=64), Parameter("sgbm.block_size", value=7)])
    assert all(r.successful for r in ok)
    assert node.config["disp_max"] == 64 and node.config["params"]["block_size"] == 7
    bad = node.set_parameters_atomically([Parameter("matcher", value="elas"),
                                          Parameter("elas.support_threshold", value=1.5)])
    assert not bad.successful and "support_threshold" in bad.reason
    assert node.config["matcher"] == "sgbm" and node.get_parameter("matcher").value == "sgbm"
    wrong_type = node.set_parameters([Parameter("sgbm.block_size", value=2.5)])
    assert not wrong_type[0].successful and "integer" in wrong_type[0].reason
    good = node.set_parameters_atomically([Parameter("matcher", value="elas"),
                                           Parameter("elas.subpixel", value=True),
                                           Parameter("preset", value="middlebury")])
    assert good.successful
    assert node.config["matcher"] == "elas" and node.config["params"]["subpixel"] is True
    assert node.config["params"]["preset"] == "middlebury" and node.config["delta_d"] == 1 / 16
    assert not node.has_parameter("P_left")  # the rig is rectify_node's alone


# --------------------------------------------------------------------------- point_cloud_node


def _plane_disparity(rig, rect, depth_mm):
    """Rectified disparity of a plane perpendicular to the rectified viewing direction."""
    w, h = rect.size
    return np.full((h, w), rect.focal_length * rect.baseline / depth_mm + rect.doffs, np.float32)


@pytest.mark.parametrize("organized", [False, True])
def test_point_cloud_node_triangulates_in_world_metres(harness, paper_rig, organized):
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode

    harness.add(PointCloudNode(**node_kwargs(harness, organized=organized)))
    out = harness.collect(PointCloud2, "points2")
    pd, pc = harness.publisher(DisparityImage, "disparity"), harness.publisher(Image, "left/image_rect_color")
    il, ir = rect_info_publishers(harness)
    harness.connect(pd, pc, il)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    geometry_publisher(harness, paper_rig, rect)
    publish_rect_infos(il, ir, paper_rig, rect, T0)
    depth_mm = 500.0
    disp = _plane_disparity(paper_rig, rect, depth_mm)
    disp[:10] = -1  # some invalid rows
    colour = np.zeros((480, 640, 3), np.uint8)
    colour[..., 0], colour[..., 1], colour[..., 2] = 10, 200, 30  # BGR
    pd.publish(convert.disparity_to_msg(disp, rect.focal_length, rect.baseline * 1e-3, 0, 100,
                                        stamp_ns=T0, frame_id="rect", doffs=rect.doffs))
    pc.publish(convert.image_to_msg(colour, "bgr8", stamp_ns=T0, frame_id="rect"))
    assert wait_for(lambda: len(out) == 1, TIMEOUT)
    msg = out[0]
    assert msg.header.frame_id == "canopy_world" and convert.stamp_to_ns(msg.header.stamp) == T0
    pts, cols = convert.cloud2_to_points(msg, organized=organized)
    if organized:
        assert pts.shape == (480, 640, 3) and not msg.is_dense
        assert np.all(np.isnan(pts[:10])) and np.isfinite(pts[10:]).all()
        pts, cols = pts[10:].reshape(-1, 3), cols[10:].reshape(-1, 3)
    else:
        assert msg.height == 1 and msg.is_dense and len(pts) == 470 * 640
    # the plane lies at 500 mm along the rectified viewing direction from the left centre
    from canopy_stereo.geometry.camera import camera_centre

    X_mm = pts.astype(np.float64) * 1e3
    dist = (X_mm - camera_centre(paper_rig.P_left)) @ rect.R_rect[2]
    np.testing.assert_allclose(dist, depth_mm, rtol=2e-4)
    assert np.all(point_depth(paper_rig.P_left, X_mm) > 0)
    assert np.all(cols == [30, 200, 10])  # RGB


def test_point_cloud_node_applies_the_mask(harness, paper_rig):
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode

    harness.add(PointCloudNode(**node_kwargs(harness, use_mask=True)))
    out = harness.collect(PointCloud2, "points2")
    pd = harness.publisher(DisparityImage, "disparity")
    pc, pm = harness.publisher(Image, "left/image_rect_color"), harness.publisher(Image, "left/mask")
    il, ir = rect_info_publishers(harness)
    harness.connect(pd, pc, pm, il)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    geometry_publisher(harness, paper_rig, rect)
    publish_rect_infos(il, ir, paper_rig, rect, T0)
    disp = _plane_disparity(paper_rig, rect, 400.0)
    mask = np.zeros((480, 640), np.uint8)
    mask[100:150, 200:300] = 255
    # the mask arrives first, the disparity last: exact-time pairing in any order
    pm.publish(convert.image_to_msg(mask, "mono8", stamp_ns=T0))
    pc.publish(convert.image_to_msg(np.zeros((480, 640, 3), np.uint8), "bgr8", stamp_ns=T0))
    time.sleep(0.1)
    assert out == []
    pd.publish(convert.disparity_to_msg(disp, rect.focal_length, 0.03, 0, 100, stamp_ns=T0, doffs=rect.doffs))
    assert wait_for(lambda: len(out) == 1, TIMEOUT)
    assert out[0].width * out[0].height == 50 * 100


# --------------------------------------------------------------------------- segment_node


def test_segment_node_grabcut_rect_and_auto(harness):
    from canopy_stereo.ros.nodes.segment import SegmentNode

    node = harness.add(SegmentNode(**node_kwargs(harness, scale=0.5)))
    out = harness.collect(Image, "left/mask")
    pub = harness.publisher(Image, "left/image_rect_color")
    harness.connect(pub)
    rng = np.random.default_rng(5)
    img = np.clip(rng.normal(128, 12, (240, 320, 3)), 0, 255).astype(np.uint8)  # grey background
    truth = np.zeros((240, 320), bool)
    cv2.ellipse(truth.view(np.uint8), (160, 120), (60, 40), 0, 0, 360, 1, -1)
    img[truth] = np.clip(rng.normal((40, 160, 50), 10, (truth.sum(), 3)), 0, 255).astype(np.uint8)
    pub.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0, frame_id="rect"))  # automatic (saturation)
    assert wait_for(lambda: len(out) == 1, TIMEOUT)
    res = node.set_parameters([Parameter("rect", value=[90, 70, 140, 100]), Parameter("iterations", value=2)])
    assert all(r.successful for r in res)
    assert not node.set_parameters([Parameter("scale", value=2.0)])[0].successful
    pub.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0 + 1, frame_id="rect"))
    assert wait_for(lambda: len(out) == 2, TIMEOUT)
    res = node.set_parameters([Parameter("rect", value=[0, 0, 0, 0]), Parameter("auto_init", value="exg")])
    assert all(r.successful for r in res) and node.settings["rect"] is None
    pub.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0 + 2, frame_id="rect"))
    assert wait_for(lambda: len(out) == 3, TIMEOUT)
    for msg in out:
        mask = convert.msg_to_image(msg, ("mono8",)) > 0
        assert msg.encoding == "mono8" and set(np.unique(convert.msg_to_image(msg))) <= {0, 255}
        iou = (mask & truth).sum() / (mask | truth).sum()
        assert iou > 0.85, iou
    assert [convert.stamp_to_ns(m.header.stamp) for m in out] == [T0, T0 + 1, T0 + 2]


def test_segment_node_propagates_the_plant_model(harness):
    """recut_every 4 over the croton frames: one full cut in four, the masks between within
    IoU 0.95 of a full GrabCut of the same frame; the share of full cuts is in /diagnostics."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.bundled import bundled_bag
    from canopy_stereo.ros.nodes.segment import SegmentNode
    from canopy_stereo.segmentation.auto import segment_plant

    frames = [convert.msg_to_image(m).copy()
              for _, m in BagReader(bundled_bag("croton")).read("/stereo/left/image_raw")] * 2
    node = harness.add(SegmentNode(**node_kwargs(harness, recut_every=4)))
    out = harness.collect(Image, "left/mask")
    pub = harness.publisher(Image, "left/image_rect_color")
    harness.connect(pub)
    for k, img in enumerate(frames):
        pub.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0 + k, frame_id="rect"))
        assert wait_for(lambda k=k: len(out) == k + 1, TIMEOUT)
    propagator = node.settings["propagator"]
    assert (propagator.full_cuts, propagator.propagated) == (2, 6)
    for msg, img in zip(out, frames):
        mask, full = convert.msg_to_image(msg, ("mono8",)) > 0, segment_plant(img) > 0
        assert (mask & full).sum() / (mask | full).sum() >= 0.95
    values = {kv.key: kv.value for kv in node.diagnostics.status().values}
    assert float(values["full cut share mean"]) == pytest.approx(0.25)
    assert not node.set_parameters([Parameter("recut_every", value=0)])[0].successful


# --------------------------------------------------------------------------- camera_node


@pytest.mark.slow
def test_camera_node_image_sequence_and_device_loss(harness, tmp_path):
    from canopy_stereo.ros.nodes.camera import CameraNode

    frames = [np.full((48, 64, 3), 40 * k, np.uint8) for k in range(1, 4)]
    pattern = str(tmp_path / "seq" / "left_%03d.png")
    node = harness.add(CameraNode(**node_kwargs(harness, device=pattern, camera_name="left",
                                                fps=50.0, loop=True)))
    out = harness.collect(Image, "left/image_raw")
    # the sequence does not exist yet: the node must stay alive and retry with back-off
    assert wait_for(lambda: node.counts["open_failures"] >= 2, TIMEOUT)
    assert out == []
    (tmp_path / "seq").mkdir()
    for k, f in enumerate(frames):
        cv2.imwrite(pattern % k, f)
    assert wait_for(lambda: len(out) >= 5, TIMEOUT)
    got = [int(convert.msg_to_image(m)[0, 0, 0]) for m in out[:5]]
    start = got.index(40)
    assert got[start:start + 3] == [40, 80, 120]  # in order, looping
    assert all(m.encoding == "bgr8" and m.header.frame_id == "left_camera_optical_frame" for m in out)
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in out]
    assert stamps == sorted(stamps) and stamps[0] > T0  # stamped at capture (wall clock)
    # the "device" disappears mid-stream, then comes back: the node resumes by itself
    import shutil

    shutil.move(str(tmp_path / "seq"), str(tmp_path / "gone"))
    failures = node.counts["open_failures"]
    assert wait_for(lambda: node.counts["open_failures"] > failures, TIMEOUT)
    n = len(out)
    shutil.move(str(tmp_path / "gone"), str(tmp_path / "seq"))
    assert wait_for(lambda: len(out) >= n + 3, TIMEOUT)


# --------------------------------------------------------------------------- hartley, executables


def test_hartley_homographies_from_parameters_give_the_same_cloud(harness, paper_rig):
    """rectify_node and point_cloud_node accept method hartley with H_left/H_right; with
    Fusiello's homographies passed that way the cloud is the Fusiello one."""
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    H = dict(method="hartley", H_left=[float(v) for v in rect.H_left.ravel()],
             H_right=[float(v) for v in rect.H_right.ravel()])
    rectify = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, **H)))
    harness.add(PointCloudNode(**node_kwargs(harness, organized=True)))  # no rig: from rectify_node
    assert rectify.rect.method == "hartley" and rectify.rect.K_rect_left is None
    color = harness.collect(Image, "left/image_rect_color")
    infos = harness.collect(CameraInfo, "left/image_rect/camera_info")
    clouds = harness.collect(PointCloud2, "points2")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    pd = harness.publisher(DisparityImage, "disparity")
    harness.connect(pl, pr, pd)
    left, right = textured_pair(paper_rig)
    pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=T0))
    pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=T0))
    assert wait_for(lambda: len(color) == 1, TIMEOUT)
    want, _ = StereoRectifier(paper_rig, rect).rectify(left, right)
    np.testing.assert_array_equal(convert.msg_to_image(color[0]), want)
    disp = _plane_disparity(paper_rig, rect, 450.0)
    # in hartley mode disparity_node publishes f = t = 0 and no principal-point shift
    pd.publish(convert.disparity_to_msg(disp, 0.0, 0.0, 0, 100, stamp_ns=T0, doffs=0.0))
    assert wait_for(lambda: len(clouds) == 1, TIMEOUT)
    pts, _ = convert.cloud2_to_points(clouds[0], organized=True)
    from canopy_stereo.geometry.triangulation import triangulate_disparity

    np.testing.assert_allclose(pts, triangulate_disparity(disp, rect, paper_rig.P_left, paper_rig.P_right)
                               * 1e-3, rtol=1e-5, atol=1e-6)
    # a projective rectification has no metric camera: its camera_info is the uncalibrated one
    assert len(infos) == 1 and not any(infos[0].p) and not any(infos[0].k)
    assert (infos[0].width, infos[0].height) == (640, 480)


@pytest.mark.slow
def test_node_executable_reads_the_rig_file(harness, repo_root, tmp_path):
    """``disparity_node --ros-args --params-file config/croton_rig.yaml`` in its own process:
    the rig file's P matrices and extras (disp_min/disp_max, elas.subpixel) become parameters."""
    import os
    import subprocess
    import sys

    from canopy_stereo.ros.context import private_domain_id

    domain = private_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = "import sys; from canopy_stereo.ros.nodes.disparity import main; sys.exit(main())"
    rig_file = repo_root / "config" / "croton_rig.yaml"
    # large best-effort samples can be lost between processes: make the inputs reliable
    # with ROS 2's standard QoS override parameters
    reliable = [f"qos_overrides./stereo/{side}/{topic}.subscription.reliability:=reliable"
                for side in ("left", "right") for topic in ("image_rect", "image_rect/camera_info")]
    proc = subprocess.Popen([sys.executable, "-c", code, "--ros-args", "--params-file", str(rig_file),
                             "-p", "matcher:=sgbm", *[a for r in reliable for a in ("-p", r)]],
                            env=env, stderr=subprocess.PIPE, text=True)
    try:
        h = harness  # on the same private domain as the node's process
        out = h.collect(DisparityImage, "disparity")
        pl, pr = h.publisher(Image, "left/image_rect"), h.publisher(Image, "right/image_rect")
        il, ir = rect_info_publishers(h)
        h.connect(pl, pr, il, ir)
        h.wait_publishers("disparity")
        from canopy_stereo.io.rig import load_rig

        rig = load_rig(rig_file)
        publish_rect_infos(il, ir, rig, fusiello_rectify(rig.P_left, rig.P_right, rig.image_size), T0)
        left, right = textured_pair(rig, 40)
        pl.publish(convert.image_to_msg(cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), "mono8", stamp_ns=T0))
        pr.publish(convert.image_to_msg(cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), "mono8", stamp_ns=T0))
        assert wait_for(lambda: len(out) == 1, 30.0)
        rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
        assert out[0].min_disparity == pytest.approx(rig.extra["disp_min"] - rect.doffs, abs=1e-4)
        assert out[0].max_disparity == pytest.approx(rig.extra["disp_max"] - rect.doffs, abs=1e-4)
        assert out[0].t == pytest.approx(rig.baseline * 1e-3, rel=1e-6)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert f"matcher sgbm, disparities [{rig.extra['disp_min']}, {rig.extra['disp_max']}]" in err


def test_disparity_thread_budget_is_per_thread_and_keeps_the_result():
    """``threads``: numba's thread count of the calling (worker) thread only; ELAS gives the
    same disparities with 1 thread as with every core."""
    import threading

    numba = pytest.importorskip("numba")
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.ros.nodes.disparity import apply_thread_budget

    rng = np.random.default_rng(3)
    right = (rng.random((96, 128)) * 255).astype(np.uint8)
    left = np.roll(right, 7, axis=1)
    seen = {}

    def work(n):
        seen[n] = (apply_thread_budget(n), numba.get_num_threads(),
                   compute_disparity(left, right, matcher="elas", disp_min=0, disp_max=16))

    main_threads = numba.get_num_threads()
    for n in (1, 0):
        t = threading.Thread(target=work, args=(n,))
        t.start()
        t.join()
    limit = int(numba.config.NUMBA_NUM_THREADS)
    assert seen[1][:2] == (1, 1) and seen[0][:2] == (limit, limit)
    assert numba.get_num_threads() == main_threads  # the caller's setting is untouched
    np.testing.assert_array_equal(seen[1][2], seen[0][2])
    assert apply_thread_budget(limit + 5) == limit
    numba.set_num_threads(main_threads)


def test_rectify_node_takes_the_rig_from_the_drivers_camera_info(harness, paper_rig):
    """use_camera_info: no rig file; the rig comes from left/camera_info + right/camera_info
    (what camera_node or any driver publishes) and rectifies as the rig file does."""
    from canopy_stereo.geometry.frames import raw_camera_calibration
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    node = harness.add(RectifyNode(**node_kwargs(harness, None, sync_slop=0.01, use_camera_info=True)))
    rect_l = harness.collect(Image, "left/image_rect")
    info_r = harness.collect(CameraInfo, "right/image_rect/camera_info")
    pl, pr = harness.publisher(Image, "left/image_raw"), harness.publisher(Image, "right/image_raw")
    il, ir = harness.publisher(CameraInfo, "left/camera_info"), harness.publisher(CameraInfo, "right/camera_info")
    harness.connect(pl, pr, il, ir)
    left, right = textured_pair(paper_rig)
    cal = {side: raw_camera_calibration(paper_rig, side) for side in ("left", "right")}
    # a pair that is not one stereo calibration (the right info is the left's) is dropped
    il.publish(convert.camera_info_msg(cal["left"], T0))
    ir.publish(convert.camera_info_msg(cal["left"], T0))
    assert wait_for(lambda: any("camera_info pair" in d for d in node.stats()["drops"]), TIMEOUT)
    assert node.rig is None
    for k in range(3):
        t = T0 + (k + 1) * 66_000_000
        il.publish(convert.camera_info_msg(cal["left"], t, frame_id="left_camera_optical_frame"))
        ir.publish(convert.camera_info_msg(cal["right"], t + 7_000_000, frame_id="left_camera_optical_frame"))
        if k:
            pl.publish(convert.image_to_msg(left, "bgr8", stamp_ns=t, frame_id="left_camera_optical_frame"))
            pr.publish(convert.image_to_msg(right, "bgr8", stamp_ns=t + 7_000_000,
                                            frame_id="left_camera_optical_frame"))
        time.sleep(0.05)
    assert wait_for(lambda: len(rect_l) >= 1 and len(info_r) >= 1, TIMEOUT)
    assert node.rig.world_unit == "m" and node.rig.baseline == pytest.approx(0.0296, abs=1e-4)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    want_l, _ = StereoRectifier(paper_rig, rect).rectify(left, right)
    got = convert.msg_to_image(rect_l[0]).astype(int)
    assert np.median(np.abs(got - cv2.cvtColor(want_l, cv2.COLOR_BGR2GRAY).astype(int))) == 0
    np.testing.assert_allclose(np.reshape(info_r[0].p, (3, 4)),
                               np.reshape(node.camera_infos(0)[1].p, (3, 4)))
    PR = np.reshape(info_r[0].p, (3, 4))
    assert -PR[0, 3] / PR[0, 0] == pytest.approx(0.0296, abs=1e-4)
    assert PR[0, 0] == pytest.approx(rect.focal_length, rel=1e-6)


def test_disparity_node_parallel_pairs_publishes_every_pair_in_stamp_order(harness, paper_rig):
    """``parallel_pairs`` 2: pairs matched at once give the maps of one-at-a-time matching,
    published in the order the pairs came."""
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    node = harness.add(DisparityNode(**node_kwargs(harness, paper_rig, matcher="elas", disp_min=16, disp_max=48,
                                                   parallel_pairs=2, waiting_pairs=8)))
    assert node.matching.workers == 2
    out = harness.collect(DisparityImage, "disparity")
    pl, pr = harness.publisher(Image, "left/image_rect"), harness.publisher(Image, "right/image_rect")
    il, ir = rect_info_publishers(harness)
    harness.connect(pl, pr, il, ir)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    shifts = (20, 40, 24, 36, 28, 32)
    greys = []
    for k, shift in enumerate(shifts):
        left, right = textured_pair(paper_rig, shift)
        gl, gr = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY), cv2.cvtColor(right, cv2.COLOR_BGR2GRAY)
        greys.append((gl, gr))
        stamp = T0 + k * 33_000_000
        publish_rect_infos(il, ir, paper_rig, rect, stamp)
        pl.publish(convert.image_to_msg(gl, "mono8", stamp_ns=stamp, frame_id="rect"))
        pr.publish(convert.image_to_msg(gr, "mono8", stamp_ns=stamp, frame_id="rect"))
    assert wait_for(lambda: len(out) == len(shifts), 4 * TIMEOUT)
    stamps = [convert.stamp_to_ns(m.header.stamp) for m in out]
    assert stamps == [T0 + k * 33_000_000 for k in range(len(shifts))]
    for msg, (gl, gr) in zip(out, greys):
        alone = compute_disparity(gl, gr, matcher="elas", disp_min=16, disp_max=48)
        wire = convert.msg_to_image(msg.image)
        valid = np.isfinite(alone) & (alone >= 16) & (alone <= 48)
        assert valid.mean() > 0.5 and np.array_equal(valid, wire >= msg.min_disparity)
        np.testing.assert_allclose(wire[valid] + rect.doffs, alone[valid], atol=1e-3)
    assert node.stats()["drops"] == {}
