"""fusion_node with poses from TF: a simulated arm carries the rig around a plant.

The arm publishes only ``base_link -> tool0`` on ``/tf``, at 50 Hz on its own clock (never at
the image stamps); ``rectify_node`` (own process) mounts the rig on ``tool0`` (``parent_frame``,
``mount``) and publishes ``tool0 -> canopy_world -> cameras`` on ``/tf_static``; ``fusion_node``
(own process, ``fixed_frame: base_link``) looks each cloud's pose up at its stamp,
interpolated. The views are rendered by the simulator's orbit (canopy_stereo.sim.multiview)
at the arm's pose at each image stamp, and each cloud is the rendered truth of its view's
plant/pot/soil pixels, so the only error left is the pose's: the registration error is the
largest displacement of a view's points between the pose fusion_node used (``view_pose``)
and the true pose, required <= 1 mm. A cloud stamped after the arm stopped publishing is
dropped with tf's reason (extrapolation into the future).

Deterministic on a loaded machine: the arm starts moving only once the test's probe is matched
with fusion_node's ``view_pose`` and ``canopy_points`` (a pose published before would be lost)
and rectify_node's latched ``/tf_static`` and fusion_node's listener are in the graph, and
once fusion_node subscribes to the arm's ``/tf`` and ``points2``; a cloud waits up to
``tf_timeout`` (2 s) for its transform, so the static transforms may still be on their way.

tf2_msgs is not on PyPI: the nodes and the arm run with the tf2_msgs the tests build
(test/support/build_tf2_msgs.py), as on a ROS install.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from canopy_stereo.geometry.frames import pose_matrix, pose_values  # noqa: E402
from canopy_stereo.geometry.transforms import invert_transform, make_transform, rotation_about_axis, transform_points  # noqa: E402
from test.support.build_tf2_msgs import environment  # noqa: E402
from test.support.ros_harness import REPO, Probe, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

T0 = 1_700_000_000_000_000_000
TF_RATE_HZ = 50.0
IMAGE_TIMES_S = [0.337 + 0.61 * i for i in range(6)]  # never on the 20 ms grid of the arm
ARM_END_S = IMAGE_TIMES_S[-1] + 0.4
#: the rig's world frame in tool0 (hand-eye): 15 deg about (1, 1, 0), offset 2, -4, 10 cm
MOUNT = make_transform(rotation_about_axis([1.0, 1.0, 0.0], np.radians(15.0)), [0.02, -0.04, 0.10])

ARM = r"""
import sys, time
import numpy as np
import rclpy
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage
from canopy_stereo.ros.convert import points_to_cloud2
from canopy_stereo.ros.tf import transform_msg
from canopy_stereo.ros.tf_listener import TF_QOS
from canopy_stereo.ros.qos import publisher_qos

data = np.load(sys.argv[1])
rclpy.init()
node = rclpy.create_node("arm", namespace="/arm_rig")
tf_pub = node.create_publisher(TFMessage, "/tf", TF_QOS)
cloud_pub = node.create_publisher(PointCloud2, "points2", publisher_qos(depth=10))
deadline = time.monotonic() + 60
while (tf_pub.get_subscription_count() < 1 or cloud_pub.get_subscription_count() < 1) \
        and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
if tf_pub.get_subscription_count() < 1 or cloud_pub.get_subscription_count() < 1:
    sys.exit("fusion_node did not subscribe to /tf and points2 within 60 s")
time.sleep(1.0)  # fusion_node's readers match these writers too (the other side of the discovery)
events = [(float(s), "tf", k) for k, s in enumerate(data["tf_times"])]
events += [(float(s) + 0.1, "cloud", k) for k, s in enumerate(data["cloud_times"])]  # 100 ms processing
events.sort()
start = time.monotonic()
for t, kind, k in events:
    delay = start + t - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    if kind == "tf":
        stamp = int(data["t0"]) + int(round(float(data["tf_times"][k]) * 1e9))
        tf_pub.publish(TFMessage(transforms=[transform_msg("base_link", "tool0", data["tf_poses"][k],
                                                           stamp_ns=stamp)]))
    else:
        stamp = int(data["t0"]) + int(round(float(data["cloud_times"][k]) * 1e9))
        n = int(data["cloud_sizes"][k])
        lo = int(data["cloud_sizes"][:k].sum())
        cloud_pub.publish(points_to_cloud2(data["points"][lo:lo + n], data["colours"][lo:lo + n],
                                           stamp_ns=stamp, frame_id="canopy_world", organized=False))
time.sleep(2.0)
print("arm done", flush=True)
rclpy.shutdown()
"""


def arm_angle_deg(t: float) -> float:
    """The arm's path: about 50 deg/s around the plant, speeding up and slowing down."""
    return 50.0 * t + 12.0 * np.sin(2.0 * t)


def orbit_pose_m(seq_args, t: float) -> np.ndarray:
    """True ``T_base_link<-canopy_world`` (metres) at time ``t``: the simulator's orbit pose
    at the arm's angle (base_link = the plant's world frame, in metres)."""
    from canopy_stereo.sim.multiview import sequence_poses

    centre, axis, rig = seq_args
    T = sequence_poses(1, "orbit", centre, axis, rig, elevation_deg=20.0, start_deg=arm_angle_deg(t))[0].copy()
    T[:3, 3] *= rig.metres_per_unit
    return T


@pytest.fixture(scope="module")
def arm_scene(tmp_path_factory):
    """The views at the image stamps and the arm's 50 Hz poses, saved for the arm process."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.sim.multiview import downscaled_rig, plant_axis, render_views
    from canopy_stereo.sim.simulate import scene_for_rig

    rig = downscaled_rig(load_rig(REPO / "config" / "croton_rig.yaml"), 2)  # 320x240: fast renders
    placed = scene_for_rig("croton", rig, seed=0)
    _, axis, centre = plant_axis(placed, rig)
    seq_args = (centre, axis, rig)
    points, colours, sizes, truth = [], [], [], []
    for t in IMAGE_TIMES_S:
        seq = render_views(placed, rig=rig, n_views=1, mode="orbit", elevation_deg=20.0,
                           start_deg=arm_angle_deg(t), supersample=1)
        view = seq.views[0]
        T_true = orbit_pose_m(seq_args, t)
        assert np.allclose(view.pose[:3, :3], T_true[:3, :3])
        keep = view.mask > 0
        pts = view.sim.xyz_left[keep] * rig.metres_per_unit
        ok = np.all(np.isfinite(pts), axis=1)
        points.append(pts[ok])
        colours.append(view.sim.left[keep][ok])
        sizes.append(int(ok.sum()))
        truth.append(T_true)
    tf_times = np.arange(0.0, ARM_END_S, 1.0 / TF_RATE_HZ)
    tf_poses = np.stack([orbit_pose_m(seq_args, t) @ invert_transform(MOUNT) for t in tf_times])
    cloud_times = np.array(IMAGE_TIMES_S + [ARM_END_S + 3.0])  # the last one: after the arm stopped
    points.append(points[0])
    colours.append(colours[0])
    sizes.append(sizes[0])
    path = tmp_path_factory.mktemp("arm") / "arm.npz"
    np.savez(path, t0=np.int64(T0), tf_times=tf_times, tf_poses=tf_poses, cloud_times=cloud_times,
             cloud_sizes=np.array(sizes), points=np.concatenate(points).astype(np.float32),
             colours=np.concatenate(colours).astype(np.uint8))
    return path, points, truth


def test_mount_pose_values_round_trip():
    np.testing.assert_allclose(pose_matrix(pose_values(MOUNT)), MOUNT, atol=1e-12)


def test_fusion_node_places_views_from_tf_at_50_hz_within_1_mm(ros_processes, tf2_msgs_build, arm_scene):
    import subprocess
    import sys

    from geometry_msgs.msg import PoseStamped
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import PointCloud2

    from canopy_stereo.ros.fusion_node import pose_to_matrix

    path, points, truth = arm_scene
    group = ros_processes
    group.env = environment(tf2_msgs_build, group.env)
    rig_file = REPO / "config" / "croton_rig.yaml"
    group.start("rectify_node", params_files=[rig_file], namespace="/arm_rig",
                params={"parent_frame": "tool0", "mount": pose_values(MOUNT)})
    fusion = group.start("fusion_node", params_files=[rig_file], namespace="/arm_rig",
                         params={"fixed_frame": "base_link", "publish_period": 0.3, "tf_timeout": 2.0})
    probe = Probe(group.domain_id, namespace="/arm_rig")
    try:
        poses = probe.subscribe(PoseStamped, "view_pose")
        models = probe.subscribe(PointCloud2, "canopy_points")
        # the arm moves only once the probe is matched with fusion_node's outputs (a view_pose
        # published before would be lost) and rectify_node's /tf_static is in the graph
        assert wait_for(lambda: (poses.subscription.get_publisher_count() >= 1
                                 and models.subscription.get_publisher_count() >= 1
                                 and probe.node.count_publishers("/tf_static") >= 1
                                 and probe.node.count_subscribers("/tf_static") >= 1), 90.0, group=group), \
            group.logs()
        arm = subprocess.Popen([sys.executable, "-c", ARM, str(path)], env=group.env, cwd=REPO,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            out, _ = arm.communicate(timeout=120)
        finally:
            if arm.poll() is None:
                arm.kill()
                arm.wait()
        assert arm.returncode == 0 and "arm done" in out, out[-3000:]
        assert wait_for(lambda: len(poses) >= len(IMAGE_TIMES_S), 20.0, group=group), group.logs()
        assert wait_for(lambda: "extrapolation into the future" in fusion.log(), 10.0, group=group), fusion.log()
        assert wait_for(lambda: len(models) >= 1, 10.0, group=group)
        with poses.lock:
            got = {stamp: deserialize_message(data, PoseStamped) for _, stamp, data in poses.items}
    finally:
        probe.close()
    assert len(got) == len(IMAGE_TIMES_S), sorted(got)  # the late cloud was not fused
    errors = []
    for k, t in enumerate(IMAGE_TIMES_S):
        msg = got[T0 + int(round(t * 1e9))]
        assert msg.header.frame_id == "base_link"
        used = pose_to_matrix(msg.pose)
        moved = transform_points(used, points[k]) - transform_points(truth[k], points[k])
        errors.append(np.linalg.norm(moved, axis=1).max())
    print("registration error per view (mm):", " ".join(f"{e * 1e3:.3f}" for e in errors))
    assert max(errors) <= 0.001
    log = fusion.log()
    assert "no transform base_link <- canopy_world at the cloud's stamp" in log and "s later" in log


def test_fuse_bag_places_a_recordings_clouds_by_its_tf(arm_scene, tmp_path, cli):
    """``canopy-stereo fuse --bag`` on the same arm recorded (points2 + /tf at 50 Hz +
    rectify_node's /tf_static with the mount): every view's pose within 1 mm of the truth, the
    cloud after the arm stopped skipped with tf's reason."""
    from canopy_stereo.bag import BagWriter
    from canopy_stereo.fusion.poses import read_poses
    from canopy_stereo.geometry.frames import FrameNames, stereo_transforms
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.convert import points_to_cloud2
    from canopy_stereo.ros.tf import (
        TF_STATIC_TOPIC,
        serialize_tf_message,
        tf_message_definition,
        transforms_to_msgs,
        write_static_transforms,
    )

    path, points, truth = arm_scene
    data = np.load(path)
    rig = load_rig(REPO / "config" / "croton_rig.yaml")
    bag = tmp_path / "arm.mcap"
    with BagWriter(bag) as w:
        static = stereo_transforms(rig, names=FrameNames(parent="tool0"), mount=MOUNT)
        write_static_transforms(w, static, T0, topic=TF_STATIC_TOPIC)
        w.add_topic("/tf", "tf2_msgs/msg/TFMessage", definition=tf_message_definition())
        events = [(T0 + int(round(t * 1e9)), "tf", k) for k, t in enumerate(data["tf_times"])]
        events += [(T0 + int(round(t * 1e9)) + 100_000_000, "cloud", k) for k, t in enumerate(data["cloud_times"])]
        for log_ns, kind, k in sorted(events):
            if kind == "tf":
                w.write("/tf", serialize_tf_message(transforms_to_msgs([("base_link", "tool0", data["tf_poses"][k])],
                                                                       log_ns)),
                        log_ns, msg_type="tf2_msgs/msg/TFMessage")
            else:
                n, lo = int(data["cloud_sizes"][k]), int(data["cloud_sizes"][:k].sum())
                w.write("/arm_rig/points2", points_to_cloud2(data["points"][lo:lo + n], data["colours"][lo:lo + n],
                                                             stamp_ns=log_ns - 100_000_000, frame_id="canopy_world",
                                                             organized=False), log_ns)
    code, out, err = cli("fuse", "--bag", bag, "--fixed-frame", "base_link", "-o", tmp_path / "fused.ply",
                         "--poses-out", tmp_path / "poses.yaml")
    assert code == 0, err
    assert "6 placed by TF in base_link" in out and "extrapolation into the future" in out
    poses = read_poses(tmp_path / "poses.yaml").poses
    errors = []
    for k, t in enumerate(IMAGE_TIMES_S):
        used = poses[f"cloud_{T0 + int(round(t * 1e9))}"]
        errors.append(np.linalg.norm(transform_points(used, points[k]) - transform_points(truth[k], points[k]),
                                     axis=1).max())
    print("fuse --bag registration error per view (mm):", " ".join(f"{e * 1e3:.3f}" for e in errors))
    assert max(errors) <= 0.001
    code, _, err = cli("fuse", "--bag", bag, "-o", tmp_path / "x.ply")
    assert code == 2 and "--fixed-frame" in err
