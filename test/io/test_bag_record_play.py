"""bag_record (a separate process, ended by SIGINT/SIGTERM) and bag playback timing/options."""
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.node import Node  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.bag import BagReader, BagWriter  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import private_domain_id, ros_context, wait_for  # noqa: E402
from canopy_stereo.ros.player import BagPlayer, parse_remaps, recorded_reliability  # noqa: E402
from canopy_stereo.ros.qos import publisher_qos, recording_qos  # noqa: E402
from canopy_stereo.ros.recorder import header_stamp_from_cdr  # noqa: E402
from test.support.ros_harness import killed_at_exit  # noqa: E402

pytestmark = pytest.mark.ros

T0 = 1_700_000_000_000_000_000


def _images(n):
    return [convert.image_to_msg(np.full((6, 8, 3), 10 * k, np.uint8), "bgr8", stamp_ns=T0 + k * 1000,
                                 frame_id=f"f{k}")
            for k in range(n)]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP])
def test_bag_record_survives_signals_with_a_valid_file(tmp_path, sig):
    out = tmp_path / "rec.mcap"
    domain = private_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = "import sys; from canopy_stereo.ros.recorder import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, "-o", str(out), "/rec_test/images"],
                            env=env, stderr=subprocess.PIPE, text=True)
    msgs = _images(5)
    with killed_at_exit(proc):
        with ros_context(domain) as ctx:
            node = Node("rec_test_pub", context=ctx, start_parameter_services=False)
            pub = node.create_publisher(Image, "/rec_test/images", publisher_qos("reliable", 10))
            assert wait_for(lambda: pub.get_subscription_count() >= 1, 30.0), "recorder did not subscribe"
            time.sleep(0.2)
            for m in msgs:
                pub.publish(m)
                time.sleep(0.05)
            time.sleep(0.5)
            node.destroy_node()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert "wrote" in err
    bag = BagReader(out)
    assert not bag.truncated
    got = [m for _, m in bag.read("/rec_test/images")]
    assert got == msgs
    rec = next(bag.messages())
    assert rec.publish_time_ns == T0  # header stamp
    rosbags = pytest.importorskip("rosbags.highlevel")
    with rosbags.AnyReader([out]) as reader:
        assert sum(1 for _ in reader.messages()) == 5


def _play_bag(tmp_path):
    path = tmp_path / "play.mcap"
    with BagWriter(path) as bag:
        for k, m in enumerate(_images(5)):
            bag.write("/cam/images", m, T0 + k * 100_000_000)  # 100 ms apart
            bag.write("/other", convert.image_to_msg(np.zeros((2, 2), np.uint8)), T0 + k * 100_000_000 + 1)
    return BagReader(path)


def test_player_keeps_timing_with_rate_offset_remap_and_loop(harness, tmp_path):
    bag = _play_bag(tmp_path)
    node = harness.add(Node("player_test", context=harness.ctx, start_parameter_services=False))
    got = []
    node.create_subscription(Image, "/stereo/images", got.append, recording_qos())
    player = BagPlayer(node, bag, rate=2.0, remap=parse_remaps(["/cam/images:=/stereo/images"]),
                       topics=["/cam/images"], depth=10)
    assert list(player.publishers) == ["/cam/images"]
    assert player.wait_for_subscribers(20.0)
    times = []
    stats = player.play(on_published=lambda m, t: times.append(t))
    assert stats.published == {"/cam/images": 5} and stats.total == 5
    gaps = np.diff(times)
    # 100 ms at rate 2 -> 50 ms (median and span: one late message on a busy machine
    # shortens the gap after it, the schedule stays)
    assert 0.045 <= np.median(gaps) < 0.1 and times[-1] - times[0] >= 0.19, gaps
    assert wait_for(lambda: len(got) == 5, 10.0)
    assert [convert.stamp_to_ns(m.header.stamp) for m in got] == [T0 + k * 1000 for k in range(5)]

    # start 0.25 s into the bag: frames 3 and 4 remain; as fast as possible
    offset = BagPlayer(node, bag, rate=0, start_offset_s=0.25, topics=["/cam/images"])
    stats = offset.play()
    assert stats.published == {"/cam/images": 2}

    # loop until stopped
    stop = threading.Event()
    count = []

    def on_pub(m, t):
        count.append(m.log_time_ns)
        if len(count) == 12:
            stop.set()

    looping = BagPlayer(node, bag, rate=10.0, loop=True, topics=["/cam/images"])
    stats = looping.play(stop=stop, on_published=on_pub)
    assert len(count) == 12 and stats.loops >= 2


def test_player_options_are_validated(tmp_path):
    from canopy_stereo.errors import CanopyStereoError

    bag = _play_bag(tmp_path)
    with ros_context() as ctx:
        node = Node("player_opts", context=ctx, start_parameter_services=False)
        try:
            with pytest.raises(CanopyStereoError, match="not in"):
                BagPlayer(node, bag, topics=["/nope"])
            with pytest.raises(CanopyStereoError, match="rate"):
                BagPlayer(node, bag, rate=-1)
        finally:
            node.destroy_node()
    with pytest.raises(CanopyStereoError, match="FROM|/from"):
        parse_remaps(["/a=/b"])
    assert recorded_reliability("- reliability: best_effort\n  depth: 1\n") == "best_effort"
    assert recorded_reliability("") == "reliable"


@pytest.mark.slow
def test_bag_play_executable_publishes_with_remap(harness, tmp_path):
    bag = _play_bag(tmp_path)
    domain = private_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    node = harness.add(Node("play_exe_test", context=harness.ctx, start_parameter_services=False))  # on `domain`
    got = []
    node.create_subscription(Image, "/played", got.append, recording_qos())
    code = "import sys; from canopy_stereo.ros.player import main; sys.exit(main())"
    res = subprocess.run([sys.executable, "-c", code, str(bag.path), "--rate", "5", "--delay", "15",
                          "--topics", "/cam/images", "--remap", "/cam/images:=/played"],
                         env=env, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "published 5 messages" in res.stdout
    assert wait_for(lambda: len(got) == 5, 10.0), len(got)


def test_header_stamp_from_cdr():
    from rclpy.serialization import serialize_message

    msg = convert.image_to_msg(np.zeros((2, 2), np.uint8), stamp_ns=1_234_567_890_123)
    assert header_stamp_from_cdr(serialize_message(msg)) == 1_234_567_890_123
    assert header_stamp_from_cdr(b"\x00\x01") is None
