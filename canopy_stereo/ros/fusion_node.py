"""``fusion_node``: fuse the stream of ``points2`` clouds into one canopy model.

Subscribes ``points2`` (``sensor_msgs/PointCloud2``, metres, the rig's world
frame as published by ``point_cloud_node``) and ``pose``
(``geometry_msgs/PoseStamped``: the rig's pose in the fusion world frame, e.g.
from the robot or a turntable driver). Each cloud is placed by the pose whose
stamp is nearest its own (within ``pose_slop`` seconds); a cloud that finds no
pose (none is published, or none close enough) is registered onto the
previous cloud by robust point-to-plane ICP when ``register_without_pose`` is
true, and dropped otherwise, or when it does not overlap (the drop is logged
with the overlap figures). The clouds are fused on a voxel grid
(:class:`canopy_stereo.fusion.incremental.IncrementalFusion`: averaging across
views, colour, view counts, free-space outlier removal when the rig is known)
and the model is published on ``canopy_points`` (``PointCloud2``, frame
``frame_id``) every ``publish_period`` seconds when it changed, a lower rate
than the clouds arrive. Each cloud fused is also reported on ``view_pose``
(``geometry_msgs/PoseStamped``, the cloud's stamp, frame ``frame_id``): the pose it was
placed with (given, looked up in TF or registered), so a robot or a test can check it.

Poses from TF (``fixed_frame`` set, e.g. ``base_link``, ``odom`` or ``map``): each cloud is
placed by ``T_fixed_frame<-cloud frame`` looked up in ``/tf`` + ``/tf_static`` at the
cloud's stamp, interpolated between the transforms around it (slerp + lerp; an arm's
joint states arrive at their own rate, not at the image stamps), through tf2_ros on a ROS
install and :class:`~canopy_stereo.ros.tf_listener.TransformListener`'s own buffer without
it. A cloud whose transform is not there yet waits up to ``tf_timeout`` seconds; then it is
dropped with tf's reason (unknown frame, frames not connected, extrapolation into the past
or future, and by how much). The pose topic is not used in this mode, nor ICP.

Reset: the service ``~/reset`` (``std_srvs/Trigger``) forgets every cloud;
the next one re-anchors the world frame when it comes without a pose.

Parameters: ``voxel_size`` (m, 0.002), ``publish_period`` (s, 2.0), ``pose_slop``
(s, 0.05), ``pose_wait`` (s, 1.0: how long a cloud waits for its pose),
``register_without_pose`` (true), ``min_overlap`` (0.5), ``max_views`` (0 = all),
``min_views`` (1), ``free_space`` (true; needs the rig: ``rig_file`` or the rig
parameters, for the left camera; the clouds must then be in the rig's world frame, the
point_cloud_node default), ``fixed_frame`` ("" = poses from the pose topic; else from TF),
``tf_timeout`` (s, 0.5), ``frame_id`` (frame of ``canopy_points``; "" = ``fixed_frame``, or
``canopy_world`` without one).
"""
from __future__ import annotations

import threading
import time
from collections import deque

import numpy as np
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.errors import RegistrationError
from canopy_stereo.fusion.incremental import IncrementalFusion
from canopy_stereo.fusion.registration import RegistrationSettings
from canopy_stereo.geometry.tf_buffer import TransformLookupError
from canopy_stereo.geometry.transforms import check_transform, make_transform
from canopy_stereo.ros.convert import cloud2_to_points, make_header, points_to_cloud2, stamp_to_ns
from canopy_stereo.ros.limits import MAX_IMAGE_PIXELS, check_cloud_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rig_from_node

#: Poses kept for matching clouds to stamps.
POSE_HISTORY = 200


def pose_to_matrix(pose) -> np.ndarray:
    """``geometry_msgs/Pose`` -> (4, 4) transform (metres); raises on a non-unit quaternion."""
    q = np.array([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w], np.float64)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or abs(n - 1.0) > 1e-3:
        raise CanopyStereoError(f"pose orientation is not a unit quaternion (norm {n:.4g})")
    x, y, z, w = q / n
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    t = [pose.position.x, pose.position.y, pose.position.z]
    return check_transform(make_transform(R, t), "pose")


def matrix_to_pose(T, pose) -> None:
    """Fill a ``geometry_msgs/Pose`` from a (4, 4) rigid transform (metres)."""
    from scipy.spatial.transform import Rotation

    T = np.asarray(T, np.float64)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (
        float(x), float(y), float(z), float(w))
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in T[:3, 3])


class FusionNode(CanopyNode):
    """Clouds + optional poses -> fused ``canopy_points``."""

    def __init__(self, node_name: str = "fusion_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_number("voxel_size", 0.002, "fusion voxel edge (m)", minimum=1e-5, maximum=10.0,
                            read_only=True)
        self.declare_number("publish_period", 2.0, "seconds between publications of canopy_points",
                            minimum=0.01, maximum=3600.0, read_only=True)
        self.declare_number("pose_slop", 0.05, "largest |stamp(pose) - stamp(cloud)| of a match (s)",
                            minimum=0.0, maximum=10.0)
        self.declare_number("pose_wait", 1.0, "seconds a cloud waits for a matching pose",
                            minimum=0.0, maximum=60.0)
        self.declare_flag("register_without_pose", True,
                          "register clouds without a pose onto the previous one (ICP)")
        self.declare_number("min_overlap", 0.5, "least overlap (fraction of points) of a registered cloud",
                            minimum=0.0, maximum=1.0, read_only=True)
        self.declare_number("max_views", 0, "clouds kept (oldest dropped); 0 = all",
                            minimum=0, maximum=100000, read_only=True)
        self.declare_number("min_views", 1, "publish voxels seen by at least this many clouds",
                            minimum=1, maximum=100000, read_only=True)
        self.declare_flag("free_space", True, "drop single-view points other views see through "
                          "(needs the rig)", read_only=True)
        self.declare_text("frame_id", "", "frame_id of canopy_points ('' = fixed_frame, or canopy_world "
                          "without one)")
        self.declare_text("fixed_frame", "", "poses from /tf + /tf_static: the frame the clouds are fused "
                          "in, e.g. base_link, odom or map ('' = poses from the pose topic)", read_only=True)
        self.declare_number("tf_timeout", 0.5, "seconds a cloud waits for its transform (fixed_frame)",
                            minimum=0.0, maximum=60.0)
        declare_rig_parameters(self)
        voxel = float(self.get_parameter("voxel_size").value)
        if not voxel > 0:
            raise CanopyStereoError(f"voxel_size must be positive, got {voxel}")
        self.P_left_m, self.image_size = self._camera()
        settings = RegistrationSettings(voxel=1.5 * voxel,
                                        min_overlap=float(self.get_parameter("min_overlap").value))
        self.fusion = IncrementalFusion(voxel, unit="m", settings=settings,
                                        max_views=int(self.get_parameter("max_views").value),
                                        free_space=bool(self.get_parameter("free_space").value),
                                        min_views=int(self.get_parameter("min_views").value))
        self._lock = threading.Lock()
        self._poses: deque = deque(maxlen=POSE_HISTORY)       # (stamp_ns, T)
        self._pending: deque = deque(maxlen=20)      # (stamp_ns, arrival s, points, colours, frame_id)
        self.fixed_frame = str(self.get_parameter("fixed_frame").value).lstrip("/")
        self.tf = None
        if self.fixed_frame:
            from canopy_stereo.ros.tf_listener import TransformListener

            self.tf = TransformListener(self)
        self._changed = False
        self._last_stamp = 0
        self.last_result = None
        self.pub = self.make_publisher(PointCloud2, "canopy_points")
        self.pub_view_pose = self.make_publisher(PoseStamped, "view_pose")
        self.sub_cloud = self.make_subscription(PointCloud2, "points2", self._on_cloud)
        if self.tf is None:
            self.sub_pose = self.make_subscription(PoseStamped, "pose", self._on_pose, depth=50)
        self.reset_service = self.create_service(Trigger, "~/reset", self._on_reset)
        self.timer = self.create_timer(float(self.get_parameter("publish_period").value),
                                       self.guarded(self._publish))
        self.pending_timer = self.create_timer(0.1, self.guarded(self._flush_pending))
        self.get_logger().info(f"fusing points2 at {voxel * 1000:g} mm voxels, publishing canopy_points "
                               f"every {self.get_parameter('publish_period').value:g} s"
                               + ("" if self.P_left_m is not None else " (no rig: no free-space test)")
                               + (f"; poses from TF ({self.tf.backend}) in {self.fixed_frame}" if self.tf else ""))

    # ------------------------------------------------------------------ set-up
    def _camera(self):
        """Left camera in metres (world -> pixels) and image size, or (None, None) without a rig."""
        try:
            rig = rig_from_node(self)
        except CanopyStereoError:
            return None, None
        s = 1.0 / rig.metres_per_unit
        return rig.P_left @ np.diag([s, s, s, 1.0]), rig.image_size

    # ------------------------------------------------------------------ inputs
    def _on_pose(self, msg: PoseStamped) -> None:
        T = pose_to_matrix(msg.pose)
        with self._lock:
            self._poses.append((stamp_to_ns(msg.header.stamp), T))
        self.count("poses_received")
        self._flush_pending()

    def _on_cloud(self, msg: PointCloud2) -> None:
        self.count("clouds_received")
        check_cloud_msg(msg, max_points=MAX_IMAGE_PIXELS if self.image_size is None
                        else self.image_size[0] * self.image_size[1])
        points, colors = cloud2_to_points(msg)
        stamp = stamp_to_ns(msg.header.stamp)
        frame = msg.header.frame_id.lstrip("/")
        with self._lock:
            if not self._poses and self.tf is None:
                pose = None
                waiting = False
            else:
                pose = self._match(stamp, frame)
                waiting = pose is None
            if waiting:
                self._pending.append((stamp, time.monotonic(), points, colors, frame))
                return
        self._add(stamp, points, colors, pose)

    def _match(self, stamp: int, frame: str):
        """The cloud's pose (4x4, cloud frame -> fusion frame), or None when not (yet) known."""
        if self.tf is not None:
            try:
                return self.tf.lookup(self.fixed_frame, frame, stamp_ns=stamp)
            except TransformLookupError:
                return None
        slop = int(float(self.get_parameter("pose_slop").value) * 1e9)
        best = min(self._poses, key=lambda p: abs(p[0] - stamp), default=None)
        if best is not None and abs(best[0] - stamp) <= slop:
            return best[1]
        return None

    def _flush_pending(self) -> None:
        """Place waiting clouds whose pose arrived; give up on those that waited too long."""
        wait = float(self.get_parameter("tf_timeout" if self.tf is not None else "pose_wait").value)
        ready, expired = [], []
        with self._lock:
            keep = deque(maxlen=self._pending.maxlen)
            while self._pending:
                stamp, arrived, points, colors, frame = item = self._pending.popleft()
                pose = self._match(stamp, frame)
                if pose is not None:
                    ready.append((stamp, points, colors, pose))
                elif time.monotonic() - arrived <= wait:
                    keep.append(item)
                elif self.tf is not None:
                    expired.append((stamp, frame))
                else:
                    ready.append((stamp, points, colors, None))
            self._pending = keep
        for stamp, frame in expired:
            self._drop_without_transform(stamp, frame, wait)
        for stamp, points, colors, pose in ready:
            self.guarded(self._add)(stamp, points, colors, pose)

    def _drop_without_transform(self, stamp: int, frame: str, waited_s: float) -> None:
        try:
            self.tf.lookup(self.fixed_frame, frame, stamp_ns=stamp)
            reason = "its transform arrived too late"
        except TransformLookupError as exc:
            reason = str(exc)
        self.drop(f"no transform {self.fixed_frame} <- {frame or '(empty frame_id)'} at the cloud's stamp "
                  f"within tf_timeout {waited_s:g} s: {reason}", "cloud")

    def _add(self, stamp: int, points, colors, pose) -> None:
        if pose is None and not bool(self.get_parameter("register_without_pose").value):
            self.drop("no pose within pose_slop and register_without_pose is false", "cloud")
            return
        try:
            with self._lock:
                res = self.fusion.add(points, colors, pose=pose, P_left=self.P_left_m,
                                      image_size=self.image_size)
                self._changed = True
                self._last_stamp = max(self._last_stamp, stamp)
        except RegistrationError as exc:
            self.drop(f"registration failed: {exc}", "cloud")
            return
        self.last_result = res
        view_pose = PoseStamped(header=make_header(stamp, self._frame_id()))
        matrix_to_pose(res.pose, view_pose.pose)
        self.pub_view_pose.publish(view_pose)
        self.count("clouds_registered" if res.registered else "clouds_placed")
        if res.registered:
            self.get_logger().info(f"cloud {res.index} registered: ICP rmse {res.rmse * 1000:.2f} mm, "
                                   f"overlap {res.overlap:.0%}")

    # ------------------------------------------------------------------ outputs
    def _publish(self) -> None:
        with self._lock:
            if not self._changed or self.fusion.view_count == 0:
                return
            fused = self.fusion.fused()
            self._changed = False
            stamp = self._last_stamp
        self.pub.publish(points_to_cloud2(fused.points, fused.colors, stamp_ns=stamp,
                                          frame_id=self._frame_id(), organized=False))
        self.count("models_published")

    def destroy_node(self):
        if self.tf is not None:
            self.tf.close()
        return super().destroy_node()

    def _frame_id(self) -> str:
        """Frame of the fused model and the view poses."""
        return self.get_parameter("frame_id").value or self.fixed_frame or "canopy_world"

    def _on_reset(self, request, response):
        with self._lock:
            n = self.fusion.view_count
            self.fusion.reset()
            self._pending.clear()
            self._poses.clear()
            self._changed = False
        self.count("resets")
        response.success = True
        response.message = f"forgot {n} cloud(s)"
        self.get_logger().info(f"reset: {response.message}")
        return response


def main(args=None) -> int:
    """``ros2 run canopy_stereo fusion_node [--ros-args --params-file RIG.yaml -p voxel_size:=0.002]``."""
    return run_node(FusionNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
