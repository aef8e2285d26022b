"""Frames, TF, CameraInfo and depth as the standard consumers read them (REP 103/104/105/118).

The consumer side is written here from the published formulas: image_geometry's
PinholeCameraModel/StereoCameraModel (Q from the CameraInfo P matrices), image_proc's
rectification maps (cv2.initUndistortRectifyMap with K, D, R, P), depth_image_proc's
point_cloud_xyz (x = (u - cx) z / fx with cx, fx from P), and tf2's transform chaining;
recorded bags are read back with rosbags.
"""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import ImageError  # noqa: E402

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.geometry.camera import decompose_projection, point_depth  # noqa: E402
from canopy_stereo.geometry.distortion import distort_pixels  # noqa: E402
from canopy_stereo.geometry.frames import FrameNames, quaternion_to_rotation, raw_camera_calibration, stereo_transforms  # noqa: E402
from canopy_stereo.geometry.rectification import fusiello_rectify  # noqa: E402
from canopy_stereo.geometry.transforms import invert_transform, transform_points  # noqa: E402
from canopy_stereo.geometry.triangulation import apply_homography  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.stereo_geometry import parse_stereo_geometry, stereo_geometry_msg  # noqa: E402
from test.support.nodes import (  # noqa: E402
    T0,
    TIMEOUT,
    geometry_publisher,
    node_kwargs,
    publish_rect_infos,
    rect_info_publishers,
)
from test.support.rigs import unequal_verged_rig  # noqa: E402

pytestmark = pytest.mark.ros


def smooth_disparity(rect, lo, hi, seed=0):
    """A smooth random disparity field (rectified pixels) with an invalid band."""
    w, h = rect.size
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(lo, hi, (6, 8)).astype(np.float32)
    d = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    d[:12] = np.nan
    d[200:220, 300:360] = np.nan
    return d


def reprojection_case(rig):
    """point_cloud_node's inputs for a smooth disparity field on ``rig`` (Fusiello): the
    rectification, the disparities (px, NaN = invalid), the DisparityImage as the node reads
    it, T_world_optical from stereo_geometry and Q from the left rectified CameraInfo."""
    from canopy_stereo.geometry.cloud_assembly import disparity_image_reprojection

    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    t = rect.baseline * rig.metres_per_unit
    disp = smooth_disparity(rect, 15.0, 60.0)
    msg = convert.msg_to_disparity(convert.disparity_to_msg(disp, rect.focal_length, t, 0, 100))
    info = convert.rectified_camera_info(rect.K_rect_left, rect.size, t, "left", stamp_ns=0,
                                         frame_id="left_camera_rect_optical_frame")
    geometry = parse_stereo_geometry(stereo_geometry_msg(rig, rect, FrameNames()))
    T = geometry.lookup("canopy_world", info.header.frame_id)
    Q = disparity_image_reprojection(msg.f, msg.t, convert.camera_info_matrices(info)[3])
    return rect, disp, msg, T, Q


@pytest.mark.parametrize("rig_name", ["paper", "verged"])
def test_camera_info_path_equals_back_mapping_and_dlt(paper_rig, rig_name):
    """point_cloud_node's path (Q from the DisparityImage and the left rectified CameraInfo,
    then T_world_optical from stereo_geometry) gives the points of the exact back-mapping +
    DLT path with the rig's P, to 1e-6 relative."""
    from canopy_stereo.geometry.cloud_assembly import cloud_from_disparity
    from canopy_stereo.geometry.frames import reproject_disparity_points

    rig = paper_rig if rig_name == "paper" else unequal_verged_rig()
    rect, disp, msg, T, Q = reprojection_case(rig)
    pts, index, depth = reproject_disparity_points(msg.disparity, Q, T=T)
    bgr = np.zeros((*disp.shape, 3), np.uint8)
    ref, _ = cloud_from_disparity(np.where(np.isfinite(disp), disp, -1), bgr, rect, rig.P_left, rig.P_right,
                                  scale=rig.metres_per_unit, organized=False)
    assert len(pts) == len(ref) == np.isfinite(disp).sum()
    scale = np.linalg.norm(ref.astype(np.float64), axis=1)
    err = np.linalg.norm(pts.astype(np.float64) - ref, axis=1) / scale
    assert err.max() < 1e-6
    # and the float64 path (before rounding to the cloud's float32) too: its only error is the
    # DisparityImage's f and t, float32 on the wire (2 roundings of 2**-24 relative each)
    from canopy_stereo.geometry.frames import reproject_disparity
    from canopy_stereo.geometry.triangulation import triangulate_disparity

    p64 = transform_points(T, reproject_disparity(msg.disparity, Q))
    r64 = triangulate_disparity(np.where(np.isfinite(disp), disp, -1), rect, rig.P_left, rig.P_right)
    ok = np.isfinite(r64[..., 2])
    rel = np.linalg.norm(p64[ok] - r64[ok] * rig.metres_per_unit, axis=1) / np.linalg.norm(
        r64[ok] * rig.metres_per_unit, axis=1)
    assert rel.max() < 1.5e-7
    # depth is Z = f t / d of the rectified left camera
    z = depth.ravel()[index]
    np.testing.assert_allclose(z, msg.f * msg.t / msg.disparity.ravel()[index], rtol=1e-6)


@pytest.mark.parametrize("organized", [False, True])
@pytest.mark.parametrize("masked", [False, True])
def test_cloud_records_path_gives_the_reference_cloud(paper_rig, organized, masked):
    """point_cloud_node's fast path (the kernel writes x, y, z, rgb rows; records_to_cloud2)
    makes the same PointCloud2, byte for byte, as the reference (points, gathered colours,
    points_to_cloud2), dense or organized, with or without a mask."""
    from canopy_stereo.geometry.frames import reproject_disparity_points, reproject_disparity_records

    rig = unequal_verged_rig()
    rect, disp, msg, T, Q = reprojection_case(rig)
    rng = np.random.default_rng(1)
    h, w = disp.shape
    bgr = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    mask = (rng.random((h, w)) > 0.3).astype(np.uint8) * 255 if masked else None
    rgb = convert.pack_bgr_image(bgr)
    pts, index, depth = reproject_disparity_points(msg.disparity, Q, T=T, mask=mask, organized=organized)
    colours = rgb if organized else rgb.reshape(-1)[index]
    if organized:
        pts = pts.reshape(h, w, 3)
    ref = convert.points_to_cloud2(pts, None, stamp_ns=7, frame_id="canopy_world", organized=organized,
                                   rgb=colours)
    records, depth2 = reproject_disparity_records(msg.disparity, Q, T=T, rgb=rgb, mask=mask,
                                                  organized=organized)
    fast = convert.records_to_cloud2(records, 7, frame_id="canopy_world",
                                     organized_shape=(h, w) if organized else None)
    assert bytes(fast.data) == bytes(ref.data)
    for field in ("height", "width", "point_step", "row_step", "is_dense", "is_bigendian", "fields", "header"):
        assert getattr(fast, field) == getattr(ref, field), field
    np.testing.assert_array_equal(depth2, depth)
    with pytest.raises(ImageError):
        convert.records_to_cloud2(records[:, :3].copy())
    with pytest.raises(ImageError):
        convert.records_to_cloud2(records, organized_shape=(h + 1, w))


@pytest.mark.parametrize("rig_name", ["verged", "paper"])
def test_raw_camera_info_rectifies_like_rectify_node(paper_rig, rig_name):
    """image_proc's maps from camera_node's CameraInfo (K, D, R, P) = rectify_node's maps.
    OpenCV's (and so image_proc's) camera model has no skew: the paper's P matrices have
    0.47-0.63 px of it, which image_proc ignores (at most |skew| * |y| ~ 0.25 px here)."""
    base = unequal_verged_rig() if rig_name == "verged" else paper_rig
    rig = replace(base, D_left=[-0.12, 0.05, 0.0008, -0.0005, 0.01],
                  D_right=[-0.10, 0.03, -0.0005, 0.0007, 0.0])
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    w, h = rig.image_size
    vv, uu = np.mgrid[0:h:7, 0:w:7]
    grid = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    for side, P, D, H_inv in (("left", rig.P_left, rig.D_left, rect.H_left_inv),
                              ("right", rig.P_right, rig.D_right, rect.H_right_inv)):
        info = convert.camera_info_msg(raw_camera_calibration(rig, side), T0,
                                       frame_id=f"{side}_camera_optical_frame")
        K, Dm, R, Pm = (np.asarray(info.k).reshape(3, 3), np.asarray(info.d), np.asarray(info.r).reshape(3, 3),
                        np.asarray(info.p).reshape(3, 4))
        assert info.distortion_model == "plumb_bob" and np.allclose(R @ R.T, np.eye(3))
        mx, my = cv2.initUndistortRectifyMap(K, Dm, R, Pm[:, :3], (w, h), cv2.CV_32FC1)
        ours = distort_pixels(P, D, apply_homography(H_inv, grid))
        theirs = np.stack([mx[vv.ravel(), uu.ravel()], my[vv.ravel(), uu.ravel()]], axis=1)
        skew_bound = abs(K[0, 1]) * 0.45 + 2e-3   # |y| = |v - cy| / fy < 0.45 in these images
        assert np.abs(ours - theirs).max() < skew_bound
        assert (abs(K[0, 1]) < 1e-9) == (rig_name == "verged")
    # stereo: P's Tx is -f * baseline in metres, the same principal point on both sides
    Pl = np.asarray(convert.camera_info_msg(raw_camera_calibration(rig, "left")).p).reshape(3, 4)
    Pr = np.asarray(convert.camera_info_msg(raw_camera_calibration(rig, "right")).p).reshape(3, 4)
    assert -Pr[0, 3] / Pr[0, 0] == pytest.approx(rig.baseline * 1e-3, rel=1e-9)
    assert np.array_equal(Pl[:, :3], Pr[:, :3]) and Pl[0, 3] == 0


def test_transforms_agree_with_camera_info_and_z_is_up(paper_rig):
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    tree = {c: (p, T) for p, c, T in stereo_transforms(paper_rig, rect)}
    # REP 104's R (raw optical -> rectified optical) is what TF says
    T_raw, T_rect = tree["left_camera_optical_frame"][1], tree["left_camera_rect_optical_frame"][1]
    R_info = np.asarray(convert.camera_info_msg(raw_camera_calibration(paper_rig, "left")).r).reshape(3, 3)
    np.testing.assert_allclose((invert_transform(T_rect) @ T_raw)[:3, :3], R_info, atol=1e-12)
    # the rectified right camera sits at +baseline along the rectified x axis
    T_lr = invert_transform(T_rect) @ tree["right_camera_rect_optical_frame"][1]
    np.testing.assert_allclose(T_lr[:3, 3], [paper_rig.baseline * 1e-3, 0, 0], atol=1e-9)
    np.testing.assert_allclose(T_lr[:3, :3], np.eye(3), atol=1e-12)
    # z-up: the croton scene stands along world -y (pot below, stem up); the z-up frame makes it +z
    parent, T_zw = tree["canopy_world"]
    assert parent == "canopy_world_z_up"
    up = T_zw[:3, :3] @ np.array([0.0, -1.0, 0.0])
    assert np.degrees(np.arccos(up[2])) < 5.0
    fwd = T_zw[:3, :3] @ decompose_projection(paper_rig.P_left).R[2]  # the cameras look along +x
    assert fwd[0] > 0.99
    # an explicit world_up in the rig file wins
    rig = paper_rig.with_extra(world_up=[0.0, -1.0, 0.0])
    T = dict((c, T) for _, c, T in stereo_transforms(rig, rect))["canopy_world"]
    np.testing.assert_allclose(T[:3, :3] @ [0, -1.0, 0], [0, 0, 1], atol=1e-12)


def test_static_transforms_serialize_like_ros():
    """Our hand-written TFMessage CDR is byte-identical to rosbags' serializer."""
    from rosbags.typesys import Stores, get_typestore

    from canopy_stereo.ros.tf import serialize_tf_message, transforms_to_msgs

    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation([0.1, -0.2, 0.3, 0.9])
    T[:3, 3] = [0.5, -1.25, 3.0]
    msgs = transforms_to_msgs([("a", "b_optical_frame", T), ("canopy_world", "c", np.eye(4))], T0 + 7)
    data = serialize_tf_message(msgs)
    store = get_typestore(Stores.ROS2_JAZZY)
    back = store.deserialize_cdr(data, "tf2_msgs/msg/TFMessage")
    assert store.serialize_cdr(back, "tf2_msgs/msg/TFMessage") == data
    t = back.transforms[0]
    assert (t.header.frame_id, t.child_frame_id) == ("a", "b_optical_frame")
    assert (t.header.stamp.sec, t.header.stamp.nanosec) == divmod(T0 + 7, 1_000_000_000)
    q = t.transform.rotation
    np.testing.assert_allclose(quaternion_to_rotation([q.x, q.y, q.z, q.w]), T[:3, :3], atol=1e-12)


def _tf_tree(transforms):
    """child -> (parent, T_parent_child) from rosbags TransformStamped objects (tf2's view)."""
    tree = {}
    for t in transforms:
        q, p = t.transform.rotation, t.transform.translation
        T = np.eye(4)
        T[:3, :3] = quaternion_to_rotation([q.x, q.y, q.z, q.w])
        T[:3, 3] = [p.x, p.y, p.z]
        tree[t.child_frame_id] = (t.header.frame_id, T)
    return tree


def _lookup(tree, target, source):
    """T_target_source by walking both frames to the root, as tf2 does."""
    def up(frame):
        out, T = {frame: np.eye(4)}, np.eye(4)
        while frame in tree:
            parent, T_pf = tree[frame]
            T = T_pf @ T
            frame = parent
            out[frame] = T
        return out

    a, b = up(target), up(source)
    common = next((f for f in a if f in b), None)
    assert common is not None, f"no TF path from {source} to {target}"
    return invert_transform(a[common]) @ b[common]


@pytest.mark.slow
def test_recorded_bag_has_tf_static_and_depth_matching_points2(tmp_path):
    """Must-show: /tf_static in a recorded bag (read back with rosbags) connects the frame of
    points2 with the camera frames; the depth image, reprojected with its CameraInfo as
    depth_image_proc does and moved with that TF, is points2."""
    from rosbags.highlevel import AnyReader

    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_bag, bundled_rig, read_truth_depths, relative_depth_errors
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    bag, rig = bundled_bag("croton"), load_rig(bundled_rig("croton"))
    out = tmp_path / "out.mcap"
    result = run_bag(bag, rig, rate=0, record=out, options=GraphOptions(segment=False, parameter_services=False))
    assert result.frames_out == 4
    with AnyReader([Path(out)]) as reader:
        by_topic = {}
        for c, _, raw in reader.messages():
            by_topic.setdefault(c.topic, []).append(reader.deserialize(raw, c.msgtype))
        types = {c.topic: c.msgtype for c in reader.connections}
    assert types["/tf_static"] == "tf2_msgs/msg/TFMessage" and len(by_topic["/tf_static"]) == 1
    tree = _tf_tree(by_topic["/tf_static"][0].transforms)
    clouds = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in by_topic["/stereo/points2"]}
    depths = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in by_topic["/stereo/left/depth"]}
    infos = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in by_topic["/stereo/left/depth/camera_info"]}
    assert len(clouds) == len(depths) == len(infos) == 4
    cloud_frame = next(iter(clouds.values())).header.frame_id
    assert cloud_frame == "canopy_world"
    for camera in ("left_camera_optical_frame", "right_camera_optical_frame",
                   "left_camera_rect_optical_frame", "right_camera_rect_optical_frame"):
        _lookup(tree, cloud_frame, camera)  # connected
    _lookup(tree, "canopy_world_z_up", cloud_frame)
    truth = read_truth_depths(bag)
    for stamp, cloud in clouds.items():
        depth_msg, info = depths[stamp], infos[stamp]
        assert depth_msg.encoding == "32FC1" and depth_msg.header.frame_id == info.header.frame_id
        z = np.frombuffer(depth_msg.data, "<f4").reshape(depth_msg.height, depth_msg.width)
        # depth_image_proc point_cloud_xyz: centre and focal length from the camera model (P)
        P = np.asarray(info.p).reshape(3, 4)
        cx, cy, fx, fy = P[0, 2], P[1, 2], P[0, 0], P[1, 1]
        v, u = np.nonzero(np.isfinite(z))
        zz = z[v, u].astype(np.float64)
        xyz_opt = np.stack([(u - cx) * zz / fx, (v - cy) * zz / fy, zz], axis=1)
        xyz_world = transform_points(_lookup(tree, cloud_frame, depth_msg.header.frame_id), xyz_opt)
        # points2 (dense: the valid pixels in row-major order), read as a PointCloud2 consumer does
        rec = np.frombuffer(cloud.data, np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3,
                                                  "offsets": [0, 4, 8], "itemsize": cloud.point_step}))
        pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
        assert len(pts) == len(xyz_world) > 0.6 * 640 * 480
        err = np.linalg.norm(pts - xyz_world, axis=1) / np.linalg.norm(xyz_world, axis=1)
        assert err.max() < 1e-5
        ns = stamp[0] * 1_000_000_000 + stamp[1]
        assert np.median(relative_depth_errors(pts, rig, truth[ns])) < 0.01


def point_cloud_inputs(harness):
    """Publishers of point_cloud_node's inputs: disparity, colour, left and right rectified
    camera_info (connected to the node)."""
    pd, pc = harness.publisher(DisparityImage, "disparity"), harness.publisher(Image, "left/image_rect_color")
    il, ir = rect_info_publishers(harness)
    harness.connect(pd, pc, il)
    return pd, pc, il, ir


def send_point_cloud_inputs(pubs, rig, rect, disp, stamp):
    """One frame of point_cloud_node's inputs as rectify_node and disparity_node send them."""
    pd, pc, il, ir = pubs
    publish_rect_infos(il, ir, rig, rect, stamp)
    pc.publish(convert.image_to_msg(np.zeros((480, 640, 3), np.uint8), "bgr8", stamp_ns=stamp, frame_id="x"))
    pd.publish(convert.disparity_to_msg(disp, rect.focal_length, rect.baseline * rig.metres_per_unit, 0, 100,
                                        stamp_ns=stamp, frame_id="left_camera_rect_optical_frame"))


def test_point_cloud_node_frames_optical_and_z_up(harness, paper_rig):
    """cloud_frame optical: points in the rectified left optical frame (no stereo_geometry
    needed); world_z_up: the same points through the z-up transform; left/depth matches."""
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode

    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    n_opt = harness.add(PointCloudNode(**node_kwargs(harness, cloud_frame="optical", organized=True)))
    out = harness.collect(PointCloud2, "points2")
    depth = harness.collect(Image, "left/depth")
    depth_info = harness.collect(CameraInfo, "left/depth/camera_info")
    pd, pc, il, ir = point_cloud_inputs(harness)
    disp = smooth_disparity(rect, 20.0, 50.0)

    def send(stamp):
        send_point_cloud_inputs((pd, pc, il, ir), paper_rig, rect, disp, stamp)

    send(T0)
    assert pytest_wait(lambda: len(out) == 1 and len(depth) == 1 and len(depth_info) == 1)
    assert out[0].header.frame_id == depth[0].header.frame_id == "left_camera_rect_optical_frame"
    opt, _ = convert.cloud2_to_points(out[0], organized=True)
    z = convert.msg_to_image(depth[0], ("32FC1",))
    np.testing.assert_array_equal(np.isnan(z), np.isnan(disp))
    np.testing.assert_allclose(opt[..., 2][np.isfinite(z)], z[np.isfinite(z)])
    t = rect.baseline * paper_rig.metres_per_unit
    np.testing.assert_allclose(z[np.isfinite(z)], rect.focal_length * t / disp[np.isfinite(disp)], rtol=1e-6)
    harness.remove(n_opt)
    n_opt.destroy_node()
    harness.add(PointCloudNode(**node_kwargs(harness, cloud_frame="world_z_up", organized=True)))
    geometry_publisher(harness, paper_rig, rect)
    harness.connect(pd, pc, il)
    time.sleep(0.2)
    send(T0 + 1)
    assert pytest_wait(lambda: len(out) == 2)
    assert out[1].header.frame_id == "canopy_world_z_up"
    zup, _ = convert.cloud2_to_points(out[1], organized=True)
    tree = {c: (p, T) for p, c, T in stereo_transforms(paper_rig, rect)}
    want = transform_points(_lookup(tree, "canopy_world_z_up", "left_camera_rect_optical_frame"), opt)
    ok = np.isfinite(want[..., 2])
    np.testing.assert_allclose(zup[ok], want[ok], rtol=1e-5, atol=1e-6)
    # in z-up, the plant's points are in front (+x) and z is height
    assert np.all(zup[ok][:, 0] > 0)


def test_point_cloud_node_holds_frames_until_stereo_geometry_arrives(harness, paper_rig):
    """A frame synced before rectify_node's latched stereo_geometry reaches point_cloud_node (a
    start-up race between topics) is held, not dropped: its world-frame cloud comes out when the
    geometry arrives, with the points of a frame sent after it."""
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode

    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    node = harness.add(PointCloudNode(**node_kwargs(harness, organized=True)))
    out = harness.collect(PointCloud2, "points2")
    pd, pc, il, ir = point_cloud_inputs(harness)
    disp = smooth_disparity(rect, 20.0, 50.0)

    def send(stamp):
        send_point_cloud_inputs((pd, pc, il, ir), paper_rig, rect, disp, stamp)

    send(T0)
    assert pytest_wait(lambda: len(node.waiting_for_geometry) == 1)
    assert out == [] and not node.drops
    geometry_publisher(harness, paper_rig, rect)
    assert pytest_wait(lambda: len(out) == 1)
    assert out[0].header.frame_id == "canopy_world" and node.waiting_for_geometry == []
    send(T0 + 1)
    assert pytest_wait(lambda: len(out) == 2)
    held, _ = convert.cloud2_to_points(out[0], organized=True)
    later, _ = convert.cloud2_to_points(out[1], organized=True)
    np.testing.assert_array_equal(held, later)
    assert np.isfinite(held[..., 2]).sum() == np.isfinite(disp).sum()


def pytest_wait(cond, timeout=TIMEOUT):
    from canopy_stereo.ros.context import wait_for

    return wait_for(cond, timeout)


def test_camera_node_publishes_a_drivers_camera_info(harness, paper_rig, tmp_path):
    """camera_node with the rig publishes <side>/camera_info (REP 104) with each frame."""
    from canopy_stereo.ros.nodes.camera import CameraNode

    pattern = str(tmp_path / "right_%03d.png")
    for k in range(3):
        cv2.imwrite(pattern % k, np.full((480, 640, 3), 50 * (k + 1), np.uint8))
    harness.add(CameraNode(**node_kwargs(harness, paper_rig, device=pattern, camera_name="right",
                                         fps=30.0, loop=True)))
    images = harness.collect(Image, "right/image_raw")
    infos = harness.collect(CameraInfo, "right/camera_info")
    assert pytest_wait(lambda: len(infos) >= 3 and len(images) >= 3)
    by_stamp = {convert.stamp_to_ns(m.header.stamp): m for m in images}
    info = infos[0]
    assert convert.stamp_to_ns(info.header.stamp) in by_stamp
    assert info.header.frame_id == images[0].header.frame_id == "left_camera_optical_frame"  # one frame per pair
    cal = raw_camera_calibration(paper_rig, "right")
    K, D, R, P = convert.camera_info_matrices(info)
    np.testing.assert_allclose(K, cal.K)
    np.testing.assert_allclose(R, cal.R)
    np.testing.assert_allclose(P, cal.P)
    # no lens distortion but R != I: the D image_proc rectifies with (all zeros would be copied)
    assert (info.width, info.height) == (640, 480) and info.distortion_model == "rational_polynomial"
    np.testing.assert_array_equal(D, [1, 0, 0, 0, 0, 1, 0, 0])
    # K is the camera's own: it projects world points as the rig's P does (through R_cam)
    cam = decompose_projection(paper_rig.P_right)
    X = np.array([[10.0, 20.0, 600.0]])
    x_cam = (cam.R @ (X[0] - cam.C))
    uv = (K @ x_cam)[:2] / (K @ x_cam)[2]
    P_w = paper_rig.P_right
    np.testing.assert_allclose(uv, (P_w @ np.append(X[0], 1))[:2] / (P_w @ np.append(X[0], 1))[2], atol=1e-6)
    assert point_depth(paper_rig.P_right, X)[0] > 0


def test_bag_recorder_writes_tf_static_from_rectify_node(harness, paper_rig, tmp_path):
    """bag_record / canopy_graph --record without tf2_msgs: the transforms of rectify_node's
    stereo_geometry go into the bag as /tf_static; bag_play then leaves that topic out
    (type not installed here) instead of failing."""
    from canopy_stereo.bag import BagReader, BagWriter
    from canopy_stereo.ros.nodes.rectify import RectifyNode
    from canopy_stereo.ros.player import BagPlayer
    from canopy_stereo.ros.recorder import BagRecorder
    from canopy_stereo.ros.tf import tf_message_class

    if tf_message_class() is not None:
        pytest.skip("tf2_msgs is installed: /tf_static is recorded as a topic")
    rectify = harness.add(RectifyNode(**node_kwargs(harness, paper_rig)))
    recorder = harness.add(BagRecorder(BagWriter(tmp_path / "rec.mcap"), ["/stereo/points2"],
                                       context=harness.ctx))
    assert pytest_wait(lambda: recorder._tf_written)
    harness.remove(recorder)
    recorder.close()
    recorder.destroy_node()
    bag = BagReader(tmp_path / "rec.mcap")
    assert bag.topics["/tf_static"].type_name == "tf2_msgs/msg/TFMessage"
    assert "transient_local" in bag.topics["/tf_static"].qos_yaml
    from rosbags.highlevel import AnyReader

    with AnyReader([tmp_path / "rec.mcap"]) as reader:
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    got = {(t.header.frame_id, t.child_frame_id) for t in msgs[0].transforms}
    assert got == {(p, c) for p, c, _ in rectify.transforms}
    player = BagPlayer(harness.helper, bag)
    assert "/tf_static" not in player.topics


def test_point_cloud_node_refuses_an_unknown_cloud_frame(harness):
    from rclpy.parameter import Parameter

    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode

    with pytest.raises(CanopyStereoError, match="cloud_frame must be one of"):
        PointCloudNode(**node_kwargs(harness, cloud_frame="map"))
    node = harness.add(PointCloudNode(**node_kwargs(harness)))
    res = node.set_parameters([Parameter("cloud_frame", value="base_link")])[0]
    assert not res.successful and "world, world_z_up, optical" in res.reason
    assert node.set_parameters([Parameter("cloud_frame", value="optical")])[0].successful


def test_disparity_node_default_range_is_the_pipelines(paper_rig):
    """One default search range: disparity_node's (from the CameraInfo pair) = the CLI's."""
    from canopy_stereo.geometry.rectification import default_disparity_range
    from canopy_stereo.ros.nodes.disparity import resolve_disparity_range, stereo_parameters

    for rig in (paper_rig, unequal_verged_rig()):
        rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
        t = rect.baseline * rig.metres_per_unit
        infos = [convert.rectified_camera_info(K, rect.size, t, side)
                 for K, side in ((rect.K_rect_left, "left"), (rect.K_rect_right, "right"))]
        f, t_info, doffs = stereo_parameters(*infos)
        assert (f, doffs) == (pytest.approx(rect.focal_length), 0.0) and t_info == pytest.approx(t)
        assert resolve_disparity_range(None, None, f, t=t_info, doffs=doffs) == default_disparity_range(rect)
    assert resolve_disparity_range(None, None, 0.0) == (0, 128)  # uncalibrated (Hartley)
    assert resolve_disparity_range(5, None, 0.0) == (5, 128)
