"""Fixtures of the ROS tests, built on the ``harness`` fixture of test/conftest.py."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

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


@pytest.fixture(scope="session")
def tf2_msgs_build(tmp_path_factory):
    """``tf2_msgs`` (TFMessage) built once per session from its ``.msg`` with the rosidl
    generators of rclpy's wheels (test/support/build_tf2_msgs.py): the folder to pass to
    ``build_tf2_msgs.environment``. Skips without a C/C++ compiler or catkin_pkg."""
    if not (shutil.which("gcc") and shutil.which("g++")):
        pytest.skip("no C/C++ compiler to build tf2_msgs' type support")
    pytest.importorskip("catkin_pkg")
    repo = Path(__file__).resolve().parents[2]
    out = tmp_path_factory.mktemp("tf2_msgs")
    env = dict(os.environ, AMENT_PREFIX_PATH=sys.prefix)
    proc = subprocess.run([sys.executable, str(repo / "test" / "support" / "build_tf2_msgs.py"), str(out)],
                          env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out
