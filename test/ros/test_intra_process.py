"""The one-process graph passes messages between its nodes over the intra-process bus
(canopy_stereo.ros.intra_process): same clouds as through DDS, outputs still on DDS for
other subscribers, keep-last queues, and no delivery to destroyed nodes."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import Image, PointCloud2  # noqa: E402

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig  # noqa: E402
from canopy_stereo.ros.context import ros_context  # noqa: E402
from canopy_stereo.ros.graph import CanopyGraph, GraphOptions  # noqa: E402
from canopy_stereo.ros.intra_process import IntraProcessBus  # noqa: E402
from canopy_stereo.ros.nodes.base import CanopyNode  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402

#: topics between the graph's nodes, and who receives them over the bus
INTERNAL = {
    "disparity_node": {"/stereo/left/image_rect", "/stereo/right/image_rect",
                       "/stereo/left/image_rect/camera_info", "/stereo/right/image_rect/camera_info"},
    "segment_node": {"/stereo/left/image_rect_color", "/stereo/disparity"},  # follow_disparity: masked
    "point_cloud_node": {"/stereo/disparity", "/stereo/left/image_rect_color",
                         "/stereo/left/image_rect/camera_info", "/stereo/left/mask"},
}


@pytest.fixture(scope="module")
def croton():
    return bundled_bag("croton"), load_rig(bundled_rig("croton"))


def _clouds(result) -> dict:
    out = {}
    for stamp, data in result.outputs["points2"]:
        points, colours = convert.cloud2_to_points(deserialize_message(data, PointCloud2))
        out[stamp] = (points, colours)
    return out


@pytest.mark.slow
def test_bus_gives_the_clouds_dds_gives(croton):
    """Masked croton clouds through the bus equal, point for point, the clouds of the same
    graph with DDS between its nodes (the reference path)."""
    bag, rig = croton
    results = {}
    for intra in (True, False):
        options = GraphOptions(use_mask=True, parameter_services=False, intra_process=intra)
        result = run_bag(bag, rig, rate=0, options=options, keep=("points2",))
        assert result.frames_out == 4 and result.frames_dropped == 0
        results[intra] = _clouds(result)
    assert sorted(results[True]) == sorted(results[False])
    for stamp, (points, colours) in results[True].items():
        ref_points, ref_colours = results[False][stamp]
        assert len(points) > 50_000
        np.testing.assert_array_equal(points, ref_points)
        np.testing.assert_array_equal(colours, ref_colours)


def test_internal_topics_skip_dds_and_outputs_stay_on_dds(croton):
    """Inside the graph only the raw images and the latched geometry are DDS subscriptions;
    a subscriber outside the graph still receives the rectified images the nodes exchange."""
    bag, rig = croton
    reader_msgs = {}
    reader = BagReader(bag)
    for side in ("left", "right"):
        reader_msgs[side] = next(m for _, m in reader.read(f"/stereo/{side}/image_raw"))
    with ros_context() as ctx:
        graph = CanopyGraph(rig, ctx, GraphOptions(use_mask=True, parameter_services=False))
        try:
            for name, topics in INTERNAL.items():
                node = graph.nodes[name]
                assert {s.topic_name for s in node.local_subscriptions} == topics, name
                assert not topics & {s.topic_name for s in node.subscriptions}, name
            # and disparity_node's pacing stamps (a few bytes; rectify_node is made first)
            assert {s.topic_name for s in graph.nodes["rectify_node"].subscriptions} == {
                "/stereo/left/image_raw", "/stereo/right/image_raw", "/stereo/disparity/matching",
                "/stereo/disparity/matched"}
            assert graph.nodes["disparity_node"].local_subscriptions[0].get_publisher_count() == 1

            probe = CanopyNode("probe", context=ctx, namespace="/stereo")
            got, clouds = [], []
            probe.create_subscription(Image, "left/image_rect", got.append, 10)
            probe.create_subscription(PointCloud2, "points2", clouds.append, 10)
            pub_l = probe.create_publisher(Image, "left/image_raw", 10)
            pub_r = probe.create_publisher(Image, "right/image_raw", 10)
            graph.add_node(probe)
            graph.spin_in_background()
            deadline = time.monotonic() + 20
            while (pub_l.get_subscription_count() < 1 or pub_r.get_subscription_count() < 1) \
                    and time.monotonic() < deadline:
                time.sleep(0.05)
            pub_l.publish(reader_msgs["left"])
            pub_r.publish(reader_msgs["right"])
            deadline = time.monotonic() + 60
            while not (got and clouds) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert len(got) == 1 and got[0].encoding == "mono8" and got[0].height == 480
            assert len(clouds) == 1 and clouds[0].width > 50_000
            stamp = convert.stamp_to_ns(reader_msgs["left"].header.stamp)
            assert convert.stamp_to_ns(clouds[0].header.stamp) == stamp
            counts = graph.nodes["point_cloud_node"].counts
            assert counts["clouds_published"] == 1
        finally:
            graph.shutdown()  # the probe is one of its nodes now: destroyed with them


def test_dds_only_graph_has_no_local_subscriptions(croton):
    _, rig = croton
    with ros_context() as ctx:
        graph = CanopyGraph(rig, ctx, GraphOptions(parameter_services=False, intra_process=False))
        try:
            assert graph.bus is None
            assert all(not n.local_subscriptions for n in graph.nodes.values())
            assert "/stereo/left/image_rect" in {s.topic_name for s in graph.nodes["disparity_node"].subscriptions}
        finally:
            graph.shutdown()


def _stamped(k: int) -> Image:
    msg = Image()
    msg.header.stamp.sec = k
    return msg


def test_local_subscription_keeps_the_newest_and_runs_in_the_node_thread():
    """Keep-last: a node that is not spinning gets only the newest ``depth`` messages, in
    order, in its own executor's thread; messages after its destruction are ignored."""
    bus = IntraProcessBus()
    with ros_context() as ctx:
        sender = CanopyNode("sender", context=ctx, intra_process=bus)
        receiver = CanopyNode("receiver", context=ctx, intra_process=bus)
        pub = sender.make_publisher(Image, "frames")
        got, threads = [], []

        def on(msg):
            got.append(msg.header.stamp.sec)
            threads.append(threading.current_thread().name)

        sub = receiver.make_subscription(Image, "frames", on, depth=2)
        assert sub.topic_name == "/stereo/frames" and sub.depth == 2
        assert not list(receiver.subscriptions)  # no DDS subscription
        sent = [_stamped(k) for k in range(5)]
        for msg in sent:
            pub.publish(msg)
        assert sub.pending() == 2 and sub.replaced == 3
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(receiver)
        worker = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.05) for _ in range(20)],
                                  name="receiver-executor")
        worker.start()
        worker.join()
        assert got == [3, 4] and set(threads) == {"receiver-executor"}
        # a subscription of a node with another name but an unpublished topic stays on DDS
        dds_sub = receiver.make_subscription(Image, "elsewhere", on)
        assert dds_sub in list(receiver.subscriptions)
        executor.shutdown()
        receiver.destroy_node()
        assert bus.subscription_count("/stereo/frames") == 0
        pub.publish(_stamped(9))  # nobody left: nothing raised, nothing delivered
        assert got == [3, 4]
        sender.destroy_node()
        assert bus.publisher_count("/stereo/frames") == 0
