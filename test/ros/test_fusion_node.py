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
from canopy_stereo.ros.convert import cloud2_to_points, make_header, points_to_cloud2  # noqa: E402
from canopy_stereo.ros.fusion_node import matrix_to_pose, pose_to_matrix  # noqa: E402

pytestmark = pytest.mark.ros

T0 = 1_700_000_000_000_000_000
TIMEOUT = 30.0
STEP = make_transform(rotation_about_axis([0, 1, 0], np.radians(3.0)), [0.002, 0.0, 0.001])


def patch_cloud_m(seed=0, n=10):
    """Curved patches about 0.65 m in front of the rig, metres, with colours."""
    rng = np.random.default_rng(seed)
    pts = []
    for _ in range(n):
        c = rng.uniform(-0.08, 0.08, 3) + [0, 0, 0.65]
        nrm = rng.normal(size=3)
        nrm /= np.linalg.norm(nrm)
        a = np.cross(nrm, [1.0, 0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(nrm, a)
        g = np.arange(-0.025, 0.025, 0.001)
        u, v = [x.ravel() for x in np.meshgrid(g, g)]
        k = u * u + v * v < 0.025 ** 2
        pts.append(c + u[k, None] * a + v[k, None] * b + 10.0 * (u[k] ** 2 + v[k] ** 2)[:, None] * nrm)
    pts = np.concatenate(pts)
    return pts, np.full((len(pts), 3), 120, np.uint8)


def test_pose_message_round_trip():
    T = make_transform(rotation_about_axis([1, 2, 3], 0.8), [0.1, -0.2, 0.3])
    msg = PoseStamped()
    matrix_to_pose(T, msg.pose)
    assert np.allclose(pose_to_matrix(msg.pose), T, atol=1e-9)
    msg.pose.orientation.w = 5.0
    with pytest.raises(Exception, match="unit quaternion"):
        pose_to_matrix(msg.pose)


def _send(pub, pts, cols, k):
    pub.publish(points_to_cloud2(pts, cols, stamp_ns=T0 + k * 100_000_000, frame_id="canopy_world",
                                 organized=False))


def _latest_model(models, n_before):
    assert wait_for(lambda: len(models) > n_before, TIMEOUT), "no canopy_points published"
    return cloud2_to_points(models[-1])


def test_fusion_node_places_clouds_by_pose_and_resets(fusion_harness):
    node, clouds, poses, reset, models = fusion_harness
    pts, cols = patch_cloud_m()
    for k in range(3):
        T = np.linalg.matrix_power(STEP, k)
        msg = PoseStamped(header=make_header(T0 + k * 100_000_000, "canopy_world"))
        matrix_to_pose(T, msg.pose)
        poses.publish(msg)
        _send(clouds, transform_points(invert_transform(T), pts), cols, k)
    assert wait_for(lambda: node.fusion.view_count == 3, TIMEOUT)
    # the node counts just after the view is fused: wait for the count
    assert wait_for(lambda: node.counts["clouds_placed"] == 3, TIMEOUT), node.counts
    assert node.counts.get("clouds_registered", 0) == 0
    assert wait_for(lambda: node.counts["models_published"] >= 1 and not node._changed, TIMEOUT)
    model, colours = _latest_model(models, 0)
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
        _send(clouds, transform_points(invert_transform(T), pts), cols, k)
        assert wait_for(lambda k=k: node.fusion.view_count == k + 1, TIMEOUT)
    # the node counts (and keeps last_result) just after the view is fused: wait for the count
    assert wait_for(lambda: node.counts["clouds_registered"] == 1, TIMEOUT), node.counts
    res = node.last_result
    assert np.allclose(res.pose, STEP, atol=1e-4) and res.overlap > 0.9
    _send(clouds, pts + [3.0, 0.0, 0.0], cols, 2)                   # 3 m away: no overlap
    assert wait_for(lambda: any("registration failed" in k for k in node.drops), TIMEOUT)
    assert node.fusion.view_count == 2
    n = len(models)
    model, _ = _latest_model(models, n - 1 if n else 0)
    d, _ = cKDTree(pts).query(model)
    assert np.median(d) < 0.00075
