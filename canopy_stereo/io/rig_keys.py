"""The keys a rig file may hold, and the check that refuses the others (a typo is an error).

A rig file is a ROS 2 parameter file under the ``/**`` wildcard: besides the rig itself
(:data:`RIG_KEYS`) it may carry the package's rig extras (:data:`EXTRA_KEYS`: rectification,
disparity range or working distance, ...) and any parameter of the package's nodes
(:data:`NODE_KEYS`), which every node started with ``--params-file`` reads. A key outside
them changes nothing, silently: ``disp_mx: 90`` would leave the range at its default. So
:func:`check_rig_keys` refuses it with one line naming the nearest valid key.
Matcher parameters may be nested (``elas: {subpixel: true}``) or dotted (``elas.subpixel``).
``test/io/test_rig_keys.py`` checks that every parameter the nodes declare is listed here.
"""
from __future__ import annotations

import difflib

from canopy_stereo.errors import RigError

#: The rig: camera matrices, distortion, image size, world unit.
RIG_KEYS = frozenset({"world_unit", "image_width", "image_height", "P_left", "P_right", "D_left", "D_right",
                      "distortion_model", "rig_file"})
#: Rig extras the package reads or writes.
EXTRA_KEYS = frozenset({
    "method", "H_left", "H_right",            # rectification (canopy-stereo rectify)
    "disp_min", "disp_max",                   # disparity search range, rectified pixels
    "near_m", "far_m",                        # working distance, metres (calibrate writes it)
    "world_up",                               # up direction of the world frame
    "mount", "camera_mount", "parent_frame", "frame_prefix", "publish_tf",  # the rig's place in a robot
    "camera_info_url", "left_camera_info_url", "right_camera_info_url",
})
#: Disparity matchers whose parameters may be given as ``<matcher>: {...}`` or ``<matcher>.<name>``.
MATCHER_GROUPS = frozenset({"elas", "sgbm"})
#: Parameters of the package's nodes (any may sit in a rig file given as ``--params-file``),
#: and rclpy's own.
NODE_KEYS = frozenset({
    # rectify_node
    "frame_id", "right_frame_id", "world_frame", "world_z_up_frame", "left_camera_frame", "right_camera_frame",
    "fps", "sync_slop", "image_transport", "skew_compensation", "use_camera_info", "max_stamp_gap", "zero_stamps",
    "follow_matcher",
    "stamp_latency", "fixed_frame", "tf_timeout",
    # disparity_node
    "matcher", "preset", "threads", "waiting_pairs", "parallel_pairs", "roi",
    "roi_margin", "roi_full_every", "roi_max_share",
    # segment_node (the seeder's settings)
    "rect", "auto_init", "depth_cue", "sure_margin", "edge_px", "colour_model", "scale", "iterations", "refine",
    "min_region", "recut_every", "follow_disparity", "propagate_scale", "max_pixels", "queue_size",
    # point_cloud_node
    "cloud_frame", "organized", "use_mask",
    # camera_node
    "camera_name", "device", "fourcc", "width", "height", "loop", "open_timeout", "read_timeout", "layout",
    "transport", "jpeg_quality",
    # fusion_node
    "voxel_size", "publish_period", "pose_slop", "pose_wait", "max_views", "min_views", "min_overlap",
    "free_space", "register_without_pose",
    # traits_node
    "max_rate", "whole_scene", "voxel_size_mm",
    # every node
    "reliability", "diagnostic_period",
    # rclpy
    "use_sim_time", "qos_overrides", "start_type_description_service",
})
#: Every key a rig file may hold.
VALID_KEYS = RIG_KEYS | EXTRA_KEYS | MATCHER_GROUPS | NODE_KEYS


def nearest_key(key: str) -> str | None:
    """The valid key closest to ``key`` (difflib's ratio, case-insensitive), or None."""
    lowered = {k.lower(): k for k in VALID_KEYS}
    close = difflib.get_close_matches(key.lower(), list(lowered), n=1, cutoff=0.6)
    return lowered[close[0]] if close else None


def check_rig_keys(params: dict, *, source: str = "rig") -> None:
    """Raise :class:`RigError` with one line for the first key of ``params`` (a
    ``ros__parameters`` mapping) that is not a valid rig-file key, naming the nearest one."""
    for key in params:
        name = str(key)
        group, _, _ = name.partition(".")
        if name in VALID_KEYS or (group in MATCHER_GROUPS and "." in name):
            continue
        near = nearest_key(name)
        hint = f"; did you mean '{near}'?" if near else "; see canopy_stereo.io.rig_keys for the valid keys"
        raise RigError(f"{source}: unknown key '{name}'{hint}")
