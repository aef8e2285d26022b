"""Helpers of the in-process node tests: node arguments, inputs, what rectify_node publishes
beside a rectified pair (used by test/ros/test_ros_nodes.py, test_ros_frames.py and others)."""
from __future__ import annotations

from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo

from canopy_stereo.ros import convert
from canopy_stereo.ros.params import rig_parameter_overrides
from canopy_stereo.sim.stereo_pair import synthetic_pair

T0 = 1_700_000_000_000_000_000
TIMEOUT = 20.0  # generous: the machine may be loaded


def node_kwargs(harness, rig=None, **params):
    overrides = (rig_parameter_overrides(rig) if rig is not None else [])
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return dict(context=harness.ctx, namespace="/stereo", parameter_overrides=overrides,
                start_parameter_services=False)


def textured_pair(rig, shift_px=20, seed=0):
    """Left/right colour images of a random texture, the right one shifted so that every
    left pixel ``u`` matches the right pixel ``u - shift_px`` (disparity ``shift_px``)."""
    w, h = rig.image_size
    left, right, _ = synthetic_pair(w, h, plane=(0, 0, shift_px), texture="blocks", colour=True, seed=seed)
    return left, right


def rect_info_publishers(harness):
    return (harness.publisher(CameraInfo, "left/image_rect/camera_info"),
            harness.publisher(CameraInfo, "right/image_rect/camera_info"))


def publish_rect_infos(il, ir, rig, rect, stamp, frames=("left_camera_rect_optical_frame",
                                                          "right_camera_rect_optical_frame")):
    """What rectify_node publishes beside a rectified pair (Fusiello)."""
    t = rect.baseline * rig.metres_per_unit
    il.publish(convert.rectified_camera_info(rect.K_rect_left, rect.size, t, "left", stamp_ns=stamp,
                                             frame_id=frames[0]))
    ir.publish(convert.rectified_camera_info(rect.K_rect_right, rect.size, t, "right", stamp_ns=stamp,
                                             frame_id=frames[1]))


def geometry_publisher(harness, rig, rect):
    """rectify_node's latched stereo_geometry, published by the test."""
    from std_msgs.msg import String

    from canopy_stereo.geometry.frames import FrameNames
    from canopy_stereo.ros.stereo_geometry import stereo_geometry_msg
    from canopy_stereo.ros.tf import latched_qos

    pub = harness.helper.create_publisher(String, "stereo_geometry", latched_qos())
    pub.publish(stereo_geometry_msg(rig, rect, FrameNames()))
    return pub
