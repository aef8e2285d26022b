"""Fixtures of the ROS tests, built on the ``harness`` fixture of test/conftest.py."""
from __future__ import annotations

import pytest

FUSION_TIMEOUT = 30.0


@pytest.fixture
def fusion_harness(harness):
    """``fusion_node`` (publish_period 0.2 s, pose_wait 0.3 s) on the harness, with the helper's
    ``points2`` and ``pose`` publishers, the ``fusion_node/reset`` client and the list of
    ``canopy_points`` received: ``(node, clouds, poses, reset, models)``, all connected."""
    pytest.importorskip("std_srvs.srv")
    from geometry_msgs.msg import PoseStamped
    from rclpy.parameter import Parameter
    from sensor_msgs.msg import PointCloud2
    from std_srvs.srv import Trigger

    from canopy_stereo.ros.context import wait_for, wait_for_subscribers
    from canopy_stereo.ros.fusion_node import FusionNode
    from canopy_stereo.ros.qos import publisher_qos, recording_qos

    helper = harness.helper
    node = harness.add(FusionNode(context=harness.ctx, parameter_overrides=[
        Parameter("publish_period", value=0.2), Parameter("pose_wait", value=0.3)]))
    models = []
    sub = helper.create_subscription(PointCloud2, "canopy_points", models.append, recording_qos())
    clouds = helper.create_publisher(PointCloud2, "points2", publisher_qos(depth=10))
    poses = helper.create_publisher(PoseStamped, "pose", publisher_qos(depth=10))
    reset = helper.create_client(Trigger, "fusion_node/reset")
    assert wait_for_subscribers([clouds, poses], FUSION_TIMEOUT)
    assert wait_for(lambda: sub.get_publisher_count() >= 1, FUSION_TIMEOUT)
    assert reset.wait_for_service(timeout_sec=FUSION_TIMEOUT)
    return node, clouds, poses, reset, models
