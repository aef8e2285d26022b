"""Multi-view fusion: merge stereo views of a plant into one 360-degree model.

The paper's stated next step (a single stereo pair sees one side of a plant
and leaves hide each other). Views are placed in one world frame either by
known rig poses (:mod:`~canopy_stereo.fusion.poses`: pose files, turntable
angles) or by registration (:mod:`~canopy_stereo.fusion.registration`:
feature matches lifted to 3-D, robust point-to-plane ICP, pose-graph loop
closure), then merged on a voxel grid (:mod:`~canopy_stereo.fusion.fuse`)
that averages overlapping points, keeps colour and per-point view counts and
removes single-view outliers that other views see through
(:mod:`~canopy_stereo.fusion.freespace`). :mod:`~canopy_stereo.fusion.coverage`
scores a model against true surface samples;
:mod:`~canopy_stereo.fusion.incremental` fuses a stream (ROS ``fusion_node``).

Frames: a view's points are in its rig frame (the world frame of its rig
file); its pose ``T`` (4x4) maps them to the common world frame. Lengths are in
the views' world unit, which all views must share.
"""
from canopy_stereo.fusion.coverage import CoverageReport, evaluate_model, surface_coverage
from canopy_stereo.fusion.errors import RegistrationError, UnitMismatchError
from canopy_stereo.fusion.freespace import DepthView
from canopy_stereo.fusion.fuse import FusedCloud, fuse_point_sets, fuse_views
from canopy_stereo.fusion.icp import IcpResult, estimate_normals, icp_point_to_plane
from canopy_stereo.fusion.incremental import AddResult, IncrementalFusion
from canopy_stereo.fusion.posegraph import PoseGraphEdge, optimize_pose_graph
from canopy_stereo.fusion.poses import PoseSet, read_poses, turntable_pose, write_pose, write_poses
from canopy_stereo.fusion.registration import (
    PairRegistration,
    RegistrationResult,
    RegistrationSettings,
    check_given_poses,
    register_pair,
    register_views,
)
from canopy_stereo.fusion.views import View, common_unit, view_from_reconstruction
from canopy_stereo.geometry.transforms import (
    check_transform,
    invert_transform,
    make_transform,
    rigid_fit,
    rotation_about_axis,
    transform_error,
    transform_points,
)

__all__ = [
    "AddResult", "CoverageReport", "DepthView", "FusedCloud", "IcpResult", "IncrementalFusion",
    "PairRegistration", "PoseGraphEdge", "PoseSet", "RegistrationError", "RegistrationResult",
    "RegistrationSettings", "UnitMismatchError", "View", "check_given_poses", "check_transform",
    "common_unit", "estimate_normals", "evaluate_model", "fuse_point_sets", "fuse_views",
    "icp_point_to_plane", "invert_transform", "make_transform", "optimize_pose_graph",
    "read_poses", "register_pair", "register_views", "rigid_fit", "rotation_about_axis",
    "surface_coverage", "transform_error", "transform_points", "turntable_pose",
    "view_from_reconstruction", "write_pose", "write_poses",
]
