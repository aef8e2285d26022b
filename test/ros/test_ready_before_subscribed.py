"""Ready before subscribed: each node loads (here: compiles, from an empty numba cache) its
kernels and allocates its buffers on a frame of the rig's size before it subscribes, and says
how long that took; so the first pair of a stream sent as soon as the nodes are subscribed
becomes a cloud, and so do all the others."""
import re
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
#: node -> the topics it subscribes to (relative to /stereo)
INPUTS = {"rectify_node": ("left/image_raw", "right/image_raw"),
          "disparity_node": ("left/image_rect", "right/image_rect", "left/image_rect/camera_info",
                             "right/image_rect/camera_info"),
          "point_cloud_node": ("disparity", "left/image_rect_color", "left/image_rect/camera_info")}
T0 = 1_760_000_000_000_000_000


def test_cold_numba_cache_first_pairs_become_clouds(tmp_path):
    """Nodes started with an empty NUMBA_CACHE_DIR; as soon as every node has subscribed, 10
    pairs at 5 Hz: 10 clouds. Each node logged its warm-up time before subscribing."""
    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    group.env["NUMBA_CACHE_DIR"] = str(tmp_path / "numba_cache")  # empty: every kernel compiles
    probe = None
    try:
        procs = group.start_graph(RIG, nodes=NODES)
        probe = Probe(group.domain_id)
        pub_left, pub_right = probe.publisher(Image, "left/image_raw"), probe.publisher(Image, "right/image_raw")
        clouds = probe.subscribe(PointCloud2, "points2")
        need = Counter(f"/stereo/{t}" for inputs in INPUTS.values() for t in inputs)  # topic -> subscribers

        def subscribed() -> bool:
            return (all(probe.node.count_subscribers(t) >= n for t, n in need.items())
                    and clouds.subscription.get_publisher_count() >= 1)

        assert wait_for(subscribed, 600.0, poll_s=0.02, group=group), group.logs()
        frames = croton_frames()
        stamps = [T0 + k * 200_000_000 for k in range(10)]
        feed_pairs(pub_left, pub_right, frames, stamps, 5.0)
        assert wait_for(lambda: set(stamps) <= set(clouds.stamps()), 60.0, group=group), (
            len(set(stamps) & set(clouds.stamps())), group.logs())
        for name in NODES:
            log = procs[name].log()
            m = re.search(r"ready in ([0-9.]+) s \((.*?)\) before subscribing", log)
            assert m and "640x480" in m.group(2), log[-2000:]
        # compiled, not loaded: the cache directory was filled by the nodes
        assert any((tmp_path / "numba_cache").rglob("*.nbi"))
        time.sleep(0.2)
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()
