"""``fusion_node`` in-process on a private DDS domain: clouds with poses, clouds registered
without poses, a cloud that does not overlap, and the reset service."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("std_srvs.srv")

from geometry_msgs.msg import PoseStamped  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from canopy_stereo.geometry.transforms import (  # noqa: E402
    invert_transform,
    make_transform,
    rotation_about_axis,
    transform_points,
)
from canopy_stereo.ros.context import wait_for  # noqa: E402
from canopy_stereo.ros.convert import make_header  # noqa: E402
from canopy_stereo.ros.fusion_node import matrix_to_pose, pose_to_matrix  # noqa: E402
from test.support.fusion import latest_model, patch_cloud_m, send_cloud  # noqa: E402

pytestmark = pytest.mark.ros

T0 = 1_700_000_000_000_000_000
TIMEOUT = 30.0
STEP = make_transform(rotation_about_axis([0, 1, 0], np.radians(3.0)), [0.002, 0.0, 0.001])


def test_pose_message_round_trip():
    T = make_transform(rotation_about_axis([1, 2, 3], 0.8), [0.1, -0.2, 0.3])
    msg = PoseStamped()
    matrix_to_pose(T, msg.pose)
    assert np.allclose(pose_to_matrix(msg.pose), T, atol=1e-9)
    msg.pose.orientation.w = 5.0
    with pytest.raises(Exception, match="unit quaternion"):
        pose_to_matrix(msg.pose)


def test_fusion_node_places_clouds_by_pose_and_resets(fusion_harness):
    node, clouds, poses, reset, models = fusion_harness
    pts, cols = patch_cloud_m()
    for k in range(3):
        T = np.linalg.matrix_power(STEP, k)
        msg = PoseStamped(header=make_header(T0 + k * 100_000_000, "canopy_world"))
        matrix_to_pose(T, msg.pose)
        poses.publish(msg)
        send_cloud(clouds, transform_points(invert_transform(T), pts), cols, k)
    assert wait_for(lambda: node.fusion.view_count == 3, TIMEOUT)
    # the node counts just after the view is fused: wait for the count
    assert wait_for(lambda: node.counts["clouds_placed"] == 3, TIMEOUT), node.counts
    assert node.counts.get("clouds_registered", 0) == 0
    assert wait_for(lambda: node.counts["models_published"] >= 1 and not node._changed, TIMEOUT)
    model, colours = latest_model(models, 0)
    d, _ = cKDTree(pts).query(model)
    assert np.median(d) < 0.00075                                  # world frame, metres
    assert colours.shape == (len(model), 3) and np.all(colours == 120)  # every view's grey, averaged
    future = reset.call_async(Trigger.Request())
    assert wait_for(future.done, TIMEOUT) and future.result().success
    assert "forgot 3 cloud(s)" in future.result().message and node.fusion.view_count == 0


def test_fusion_node_registers_clouds_without_pose_and_drops_non_overlapping(fusion_harness):
    node, clouds, _, _, models = fusion_harness
    pts, cols = patch_cloud_m()
    for k in range(2):
        T = np.linalg.matrix_power(STEP, k)
        send_cloud(clouds, transform_points(invert_transform(T), pts), cols, k)
        assert wait_for(lambda k=k: node.fusion.view_count == k + 1, TIMEOUT)
    # the node counts (and keeps last_result) just after the view is fused: wait for the count
    assert wait_for(lambda: node.counts["clouds_registered"] == 1, TIMEOUT), node.counts
    res = node.last_result
    assert np.allclose(res.pose, STEP, atol=1e-4) and res.overlap > 0.9
    send_cloud(clouds, pts + [3.0, 0.0, 0.0], cols, 2)                   # 3 m away: no overlap
    assert wait_for(lambda: any("registration failed" in k for k in node.drops), TIMEOUT)
    assert node.fusion.view_count == 2
    n = len(models)
    model, _ = latest_model(models, n - 1 if n else 0)
    d, _ = cKDTree(pts).query(model)
    assert np.median(d) < 0.00075
