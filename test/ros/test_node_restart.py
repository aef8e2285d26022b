"""Known good, kept: a node process killed (SIGKILL) and restarted 2 s later rejoins the graph
without restarting the others (it warms up, subscribes, and clouds flow again). The disparity
node: the longest warm-up (ELAS)."""
import signal
import time
from collections import Counter

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from sensor_msgs.msg import Image, PointCloud2  # noqa: E402

from canopy_stereo.ros.context import private_domain_id  # noqa: E402
from test.conftest import REPO  # noqa: E402
from test.support.ros_harness import Probe, ProcessGroup, croton_frames, feed_pairs, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

RIG = REPO / "config" / "croton_rig.yaml"
NODES = ("rectify_node", "disparity_node", "point_cloud_node")
INPUTS = ("left/image_raw", "right/image_raw", "left/image_rect", "right/image_rect", "left/image_rect/camera_info",
          "right/image_rect/camera_info", "disparity", "left/image_rect_color", "left/image_rect/camera_info")
T0 = 1_770_000_000_000_000_000
PERIOD_NS = 200_000_000


def test_a_killed_node_restarted_rejoins(tmp_path, victim="disparity_node"):
    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    probe = None
    try:
        procs = group.start_graph(RIG, nodes=NODES)
        probe = Probe(group.domain_id)
        pub_l, pub_r = probe.publisher(Image, "left/image_raw"), probe.publisher(Image, "right/image_raw")
        clouds = probe.subscribe(PointCloud2, "points2")
        need = Counter(f"/stereo/{t}" for t in INPUTS)

        def connected() -> bool:
            return (all(probe.node.count_subscribers(t) >= n for t, n in need.items())
                    and clouds.subscription.get_publisher_count() >= 1)

        assert wait_for(connected, 180.0, group=group), group.logs()
        frames = croton_frames()
        # the probe sees every reader, but two nodes may discover each other only at the next
        # discovery announcement (seen: rectify_node -> disparity_node 2 s later): 30 pairs
        before = [T0 + k * PERIOD_NS for k in range(30)]
        feed_pairs(pub_l, pub_r, frames, before, 5.0)
        assert wait_for(lambda: len(set(before) & set(clouds.stamps())) >= 5, 20.0, group=group), group.logs()
        procs[victim].proc.send_signal(signal.SIGKILL)
        procs[victim].proc.wait(10)
        group.processes.remove(procs[victim])
        time.sleep(2.0)
        restarted = group.start(victim, params_files=[RIG])
        # the dead process's readers may still be counted until their lease ends: wait for the new
        # one to say it is ready (it subscribes right after), then for the graph
        assert wait_for(lambda: "before subscribing" in restarted.log(), 180.0, group=group), group.logs()
        assert wait_for(connected, 60.0, group=group), group.logs()
        time.sleep(1.0)
        # the same after the restart (a new participant): 30 pairs, of which at least 5 become clouds
        after = [T0 + 10**11 + k * PERIOD_NS for k in range(30)]
        feed_pairs(pub_l, pub_r, frames, after, 5.0)
        assert wait_for(lambda: len(set(after) & set(clouds.stamps())) >= 5, 20.0, group=group), (
            len(set(after) & set(clouds.stamps())), group.logs())
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()
