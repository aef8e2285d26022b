"""Compressed camera streams into the node processes, as usb_cam/gscam (format ``jpeg``) and
image_transport's compressed publisher (``bgr8; jpeg compressed bgr8``) send them: a stand-in
driver publishes JPEG (quality 95) ``<side>/image_raw/compressed`` pairs of the croton at
10 Hz to rectify_node (``image_transport: compressed``), disparity_node and point_cloud_node,
one process each. The raw path is the same processes with rectify_node on ``image_raw``."""
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import CompressedImage, Image, PointCloud2  # noqa: E402

from canopy_stereo.io.image_codec import encode_compressed  # noqa: E402
from canopy_stereo.ros.compressed import compressed_msg  # noqa: E402
from canopy_stereo.ros.context import private_domain_id  # noqa: E402
from canopy_stereo.ros.convert import msg_to_image  # noqa: E402
from test.conftest import REPO  # noqa: E402
from test.support.ros_harness import Probe, ProcessGroup, croton_frames, feed_pairs, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

RIG = REPO / "config" / "croton_rig.yaml"
RATE_HZ = 10.0
PERIOD_NS = int(1e9 / RATE_HZ)
T0 = 1_760_000_000_000_000_000
PAIRS = 20
QUALITY = 95


def _jpeg_maker(fmt: str | None):
    """``make_msg`` for feed_pairs: JPEG at QUALITY with ``format`` ``fmt`` (None: image_transport's)."""
    def make(image, frame_id):
        it_format, data = encode_compressed(image, codec="jpeg", quality=QUALITY)
        return compressed_msg(data, it_format if fmt is None else fmt, frame_id=frame_id)
    return make


def _median_depths(received, stamps) -> dict:
    """stamp -> median of the valid depths (m) of the ``left/depth`` images with those stamps."""
    out = {}
    for _, stamp, data in list(received.items):
        if stamp in stamps:
            depth = msg_to_image(deserialize_message(data, Image))
            out[stamp] = float(np.median(depth[np.isfinite(depth) & (depth > 0)]))
    return out


def _stream(probe, group, stamps, make_msg=None) -> None:
    feed_pairs(probe.pub_left, probe.pub_right, probe.frames, stamps, RATE_HZ, make_msg=make_msg)
    wait_for(lambda: set(stamps) <= set(probe.points.stamps()), 5.0, group=group)


def _warm_up(probe, group, stamp: int, make_msg=None) -> None:
    deadline = time.monotonic() + 120.0
    start = len(probe.points)
    while len(probe.points) == start and time.monotonic() < deadline:
        feed_pairs(probe.pub_left, probe.pub_right, probe.frames, [stamp], 1.0, make_msg=make_msg)
        stamp += PERIOD_NS
        wait_for(lambda: len(probe.points) > start, 2.0, group=group)
    assert len(probe.points) > start, group.logs()
    time.sleep(1.0)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Raw pairs through the processes, then rectify_node restarted on compressed input and
    fed the same frames as JPEG with both formats; returns what came out."""
    group = ProcessGroup(private_domain_id(), tmp_path_factory.mktemp("compressed_logs"))
    probe = None
    try:
        group.start_graph(RIG, nodes=("disparity_node", "point_cloud_node"))
        rectify = group.start("rectify_node", params_files=[RIG])
        probe = Probe(group.domain_id)
        probe.frames = croton_frames()
        probe.pub_left = probe.publisher(Image, "left/image_raw")
        probe.pub_right = probe.publisher(Image, "right/image_raw")
        probe.points = probe.subscribe(PointCloud2, "points2")
        probe.depth = probe.subscribe(Image, "left/depth")
        assert wait_for(lambda: probe.pub_left.get_subscription_count() >= 1
                        and probe.points.subscription.get_publisher_count() >= 1, 60.0, group=group), group.logs()
        _warm_up(probe, group, T0 - 10**12)
        raw = [T0 + k * PERIOD_NS for k in range(PAIRS)]
        _stream(probe, group, raw)
        rectify.stop()
        group.processes.remove(rectify)
        group.start("rectify_node", params_files=[RIG], params={"image_transport": "compressed"})
        probe.pub_left = probe.publisher(CompressedImage, "left/image_raw/compressed")
        probe.pub_right = probe.publisher(CompressedImage, "right/image_raw/compressed")
        assert wait_for(lambda: probe.pub_left.get_subscription_count() >= 1
                        and probe.pub_right.get_subscription_count() >= 1, 60.0, group=group), group.logs()
        _warm_up(probe, group, T0 + 10**11, _jpeg_maker("jpeg"))
        plain = [T0 + 2 * 10**11 + k * PERIOD_NS for k in range(PAIRS)]
        _stream(probe, group, plain, _jpeg_maker("jpeg"))
        transport = [T0 + 3 * 10**11 + k * PERIOD_NS for k in range(PAIRS)]
        _stream(probe, group, transport, _jpeg_maker(None))
        time.sleep(0.5)
        yield {"raw": raw, "jpeg": plain, "image_transport": transport, "probe": probe, "group": group}
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()


@pytest.mark.parametrize("fmt", ["jpeg", "image_transport"])
def test_compressed_pairs_become_clouds(runs, fmt):
    """>= 95 % of the JPEG pairs (format 'jpeg' or 'bgr8; jpeg compressed bgr8') become clouds."""
    stamps = runs[fmt]
    got = set(runs["probe"].points.stamps()) & set(stamps)
    raw = set(runs["probe"].points.stamps()) & set(runs["raw"])
    print(f"{fmt}: {len(got)} clouds of {len(stamps)} pairs (raw path: {len(raw)} of {len(runs['raw'])})")
    assert len(got) >= 0.95 * len(stamps), (fmt, len(got), len(raw), runs["group"].logs())


@pytest.mark.parametrize("fmt", ["jpeg", "image_transport"])
def test_jpeg_95_depth_matches_the_raw_path(runs, fmt):
    """Median depth of each frame from JPEG quality 95 within 0.1 % of the raw frame's."""
    probe = runs["probe"]
    raw = _median_depths(probe.depth, set(runs["raw"]))
    comp = _median_depths(probe.depth, set(runs[fmt]))
    n = len(probe.frames)
    by_frame_raw = {(s - runs["raw"][0]) // PERIOD_NS % n: d for s, d in raw.items()}
    by_frame = {(s - runs[fmt][0]) // PERIOD_NS % n: d for s, d in comp.items()}
    common = sorted(set(by_frame_raw) & set(by_frame))
    assert common, (raw, comp)
    rel = [abs(by_frame[k] - by_frame_raw[k]) / by_frame_raw[k] for k in common]
    print(f"{fmt}: median depth difference vs raw, max over {len(common)} frames: {max(rel) * 100:.4f} %")
    assert max(rel) <= 0.001, rel
