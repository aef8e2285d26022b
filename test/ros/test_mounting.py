"""Mounting a rig in a robot's TF tree: the frame maths (geometry/frames.py) against written-out
products, rectify_node's mounting parameters, and point_cloud_node's ``cloud_frame: parent``."""
from __future__ import annotations

import time

import numpy as np
import pytest

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.frames import (
    FrameNames,
    mount_transform,
    pose_matrix,
    pose_values,
    prefixed_frames,
    stereo_extrinsics,
    stereo_transforms,
    world_z_up_transform,
)
from canopy_stereo.geometry.rectification import fusiello_rectify
from canopy_stereo.geometry.transforms import invert_transform, make_transform, rotation_about_axis, transform_points

HAND_EYE = make_transform(rotation_about_axis([0.2, 1.0, 0.1], 0.7), [0.05, -0.02, 0.13])


def test_pose_matrix_reads_seven_numbers_and_names_the_problem():
    T = pose_matrix([1, 2, 3, 0, 0, np.sin(0.25), np.cos(0.25)])
    np.testing.assert_allclose(T, make_transform(rotation_about_axis([0, 0, 1], 0.5), [1, 2, 3]), atol=1e-15)
    np.testing.assert_allclose(pose_matrix(pose_values(HAND_EYE)), HAND_EYE, atol=1e-12)
    with pytest.raises(RigError, match="mount must be seven finite numbers .* got 6"):
        pose_matrix([0, 0, 0, 0, 0, 1])
    with pytest.raises(RigError, match="camera_mount: the quaternion .* norm 1, got 2"):
        pose_matrix([0, 0, 0, 0, 0, 0, 2], name="camera_mount")


def test_prefixed_frames_prefix_every_rig_frame_but_the_parent():
    names = prefixed_frames(FrameNames(world_z_up="", parent="base_link"), "rig_a/")
    assert names.world == "rig_a/canopy_world" and names.rect_left == "rig_a/left_camera_rect_optical_frame"
    assert names.world_z_up == "" and names.parent == "base_link"
    with pytest.raises(RigError, match="frame_prefix must not start with '/'"):
        prefixed_frames(FrameNames(), "/rig_a/")


def test_mounted_tree_and_camera_mount_equal_written_out_products(paper_rig):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    T_world_cam = stereo_extrinsics(paper_rig)[("raw", "left")]
    # a hand-eye calibration gives the left camera in tool0: the world frame follows
    M = mount_transform(paper_rig, camera_mount=pose_values(HAND_EYE))
    np.testing.assert_allclose(M @ T_world_cam, HAND_EYE, atol=1e-12)
    np.testing.assert_allclose(mount_transform(paper_rig, mount=pose_values(HAND_EYE)), HAND_EYE, atol=1e-12)
    names = FrameNames(parent="tool0")
    tree = {c: (p, T) for p, c, T in stereo_transforms(paper_rig, rect, names=names, mount=M)}
    assert tree["canopy_world"][0] == "tool0" and tree["canopy_world_z_up"][0] == "canopy_world"
    assert len(tree) == 6  # world, z-up, four cameras: each frame has one parent
    np.testing.assert_allclose(tree["canopy_world_z_up"][1], invert_transform(world_z_up_transform(paper_rig)))
    T_tool_cam = tree["canopy_world"][1] @ tree["left_camera_optical_frame"][1]
    np.testing.assert_allclose(T_tool_cam, HAND_EYE, atol=1e-12)
    with pytest.raises(RigError, match="not both"):
        mount_transform(paper_rig, mount=pose_values(HAND_EYE), camera_mount=pose_values(HAND_EYE))




@pytest.mark.ros
@pytest.mark.slow
def test_rectify_node_mounting_parameters(harness, paper_rig):
    from canopy_stereo.ros.nodes.rectify import RectifyNode
    from test.ros.test_ros_nodes import node_kwargs

    node = harness.add(RectifyNode(**node_kwargs(harness, paper_rig, parent_frame="tool0", frame_prefix="arm/",
                                                 camera_mount=pose_values(HAND_EYE), publish_tf=False)))
    tree = {c: (p, T) for p, c, T in node.transforms}
    assert tree["arm/canopy_world"][0] == "tool0"
    np.testing.assert_allclose(tree["arm/canopy_world"][1] @ tree["arm/left_camera_optical_frame"][1], HAND_EYE,
                               atol=1e-12)
    assert node.message_frames == ("arm/left_camera_rect_optical_frame",) * 2  # one stereo frame, prefixed
    assert node.tf_transforms == []  # the robot's URDF owns the frames
    for bad, match in (({"mount": [0.0] * 6 + [1.0]}, "need parent_frame"),
                       ({"parent_frame": "base_link", "mount": [0.0, 0.0, 1.0]}, "seven finite numbers"),
                       ({"parent_frame": "/base_link"}, "must not start with '/'")):
        with pytest.raises(RigError, match=match):
            RectifyNode(**node_kwargs(harness, paper_rig, **bad))


@pytest.mark.ros
@pytest.mark.slow
def test_point_cloud_node_cloud_frame_parent(harness, paper_rig):
    """cloud_frame parent: the world-frame points moved by the mount, frame_id the robot frame."""
    from sensor_msgs.msg import PointCloud2
    from std_msgs.msg import String

    from canopy_stereo.ros import convert
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode
    from canopy_stereo.ros.stereo_geometry import stereo_geometry_msg
    from canopy_stereo.ros.tf import latched_qos
    from test.ros.test_ros_frames import point_cloud_inputs, pytest_wait, send_point_cloud_inputs, smooth_disparity
    from test.ros.test_ros_nodes import node_kwargs

    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    names = FrameNames(parent="base_link")
    transforms = stereo_transforms(paper_rig, rect, names=names, mount=HAND_EYE)
    geometry = harness.helper.create_publisher(String, "stereo_geometry", latched_qos())
    geometry.publish(stereo_geometry_msg(paper_rig, rect, names, transforms=transforms))
    out = harness.collect(PointCloud2, "points2")
    harness.add(PointCloudNode(**node_kwargs(harness, cloud_frame="world", organized=True)))
    pubs = point_cloud_inputs(harness)
    disp = smooth_disparity(rect, 20.0, 50.0)
    time.sleep(0.3)
    send_point_cloud_inputs(pubs, paper_rig, rect, disp, 1_000)
    assert pytest_wait(lambda: len(out) == 1)
    world, _ = convert.cloud2_to_points(out[0], organized=True)
    for node in list(harness.nodes):
        if isinstance(node, PointCloudNode):
            harness.remove(node)
            node.destroy_node()
    harness.add(PointCloudNode(**node_kwargs(harness, cloud_frame="parent", organized=True)))
    harness.connect(*pubs[:3])
    time.sleep(0.3)
    send_point_cloud_inputs(pubs, paper_rig, rect, disp, 2_000)
    assert pytest_wait(lambda: len(out) == 2)
    assert out[1].header.frame_id == "base_link"
    parent, _ = convert.cloud2_to_points(out[1], organized=True)
    ok = np.isfinite(world[..., 2])
    np.testing.assert_allclose(parent[ok], transform_points(HAND_EYE, world[ok].astype(np.float64)), atol=2e-6)
