"""The whole graph: bundled bags replayed through the real nodes, bad input, launch (the run and demo
commands: test/cli/test_run.py, test_demo.py)."""
import ast
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.geometry.rectification import fusiello_rectify  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.bundled import (  # noqa: E402
    bundled_bag,
    bundled_rig,
    read_truth_depths,
    relative_depth_errors,
    write_stereo_bag,
)
from canopy_stereo.ros.graph import GraphOptions  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def croton():
    bag, rig = bundled_bag("croton"), load_rig(bundled_rig("croton"))
    return bag, rig


def test_bundled_bags_are_small_and_complete():
    sizes = sum(p.stat().st_size for p in (REPO / "bags").glob("*.mcap"))
    assert sizes <= 15e6
    croton = BagReader(bundled_bag("croton"))
    assert not croton.truncated
    assert croton.topics["/stereo/left/image_raw"].message_count >= 3
    assert croton.topics["/stereo/right/image_raw"].message_count == croton.topics["/truth/left/depth"].message_count
    plants = BagReader(bundled_bag("plants"))
    _, left = next(plants.read("/stereo/left/image_raw"))
    assert (left.width, left.height, left.encoding) == (710, 496, "bgr8")
    rig = load_rig(bundled_rig("plants"))
    assert rig.image_size == (710, 496) and rig.baseline == pytest.approx(169.843)


@pytest.mark.slow
def test_croton_bag_through_the_real_nodes_is_metric(croton, tmp_path):
    """One PointCloud2 per frame, median depth error < 1 % against the scene's truth,
    DisparityImage f/t from the rig; the recorded outputs read back with rosbags."""
    bag, rig = croton
    out = tmp_path / "outputs.mcap"
    result = run_bag(bag, rig, rate=0, record=out, keep=("points2", "disparity"),
                     options=GraphOptions(segment=True, parameter_services=False))
    left_stamps = [convert.stamp_to_ns(m.header.stamp)
                   for _, m in BagReader(bag).read("/stereo/left/image_raw")]
    assert result.frames_in == len(left_stamps) == 4
    assert result.frames_out == 4 and result.frames_dropped == 0
    clouds = sorted(result.outputs["points2"])
    assert [s for s, _ in clouds] == left_stamps  # exactly one cloud per frame
    truth = read_truth_depths(bag)
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    for stamp, data in clouds:
        msg = deserialize_message(data, PointCloud2)
        assert msg.header.frame_id == "canopy_world"
        points, colors = convert.cloud2_to_points(msg)
        assert len(points) > 0.6 * 640 * 480 and colors.shape == (len(points), 3)
        errors = relative_depth_errors(points, rig, truth[stamp])
        assert np.median(errors) < 0.01, np.median(errors)
    for _stamp, data in result.outputs["disparity"]:
        d = deserialize_message(data, DisparityImage)
        assert d.f == pytest.approx(rect.focal_length, rel=1e-6)
        assert d.t == pytest.approx(rig.baseline * rig.metres_per_unit, rel=1e-6)
        assert d.min_disparity == pytest.approx(rig.extra["disp_min"] - rect.doffs, abs=1e-4)
    recorded = BagReader(out)
    assert recorded.topics["/stereo/points2"].message_count == 4
    assert recorded.topics["/stereo/left/mask"].message_count == 4
    assert recorded.topics["/stereo/right/image_rect/camera_info"].message_count == 4
    assert recorded.topics["/stereo/left/depth"].message_count == 4
    assert recorded.topics["/tf_static"].message_count == 1
    rosbags = pytest.importorskip("rosbags.highlevel")
    with rosbags.AnyReader([out]) as reader:
        conns = [c for c in reader.connections if c.topic == "/stereo/disparity"]
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=conns)]
    assert len(msgs) == 4 and msgs[0].t == pytest.approx(0.029628, abs=1e-5)


def _bad_input_bag(path, croton_bag):
    """Four frames: good, wrong encoding, wrong size, good."""
    reader = BagReader(croton_bag)
    lefts = [convert.msg_to_image(m) for _, m in reader.read("/stereo/left/image_raw")]
    rights = [convert.msg_to_image(m) for _, m in reader.read("/stereo/right/image_raw")]
    from canopy_stereo.bag import BagWriter

    t0 = 1_704_067_200_000_000_000
    with BagWriter(path, chunk_size=1 << 20) as bag:  # about one frame per chunk
        for k in range(4):
            t = t0 + k * 100_000_000
            left, right, enc = lefts[k], rights[k], "bgr8"
            if k == 1:
                left, enc = left.astype(np.uint16) * 256, "bgr16"
            if k == 2:
                left, right = left[::2, ::2].copy(), right[::2, ::2].copy()
            bag.write("/stereo/left/image_raw", convert.image_to_msg(left, enc, stamp_ns=t, frame_id="l"), t)
            bag.write("/stereo/right/image_raw", convert.image_to_msg(right, "bgr8", stamp_ns=t + 4_000_000,
                                                                      frame_id="r"),
                      t + 4_000_000)
    return path


@pytest.mark.slow
def test_bad_input_keeps_the_graph_alive(croton, tmp_path):
    bag, rig = croton
    bad = _bad_input_bag(tmp_path / "bad.mcap", bag)
    options = GraphOptions(matcher="sgbm", segment=False, parameter_services=False)
    result = run_bag(bad, rig, rate=0, options=options, idle_s=1.0)
    assert (result.frames_in, result.frames_out, result.frames_dropped) == (4, 2, 2)
    drops = " | ".join(result.graph_stats["rectify_node"]["drops"])
    assert "'bgr16' not accepted" in drops and "320x240 but 640x480" in drops
    text = "\n".join(result.summary_lines())
    assert "rectify_node dropped" in text

    # the same bag cut in the middle of its data: the readable frames still go through
    data = bad.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.55)])
    result = run_bag(cut, rig, rate=0, options=options, idle_s=1.0)
    assert result.truncated and "truncated" in "\n".join(result.summary_lines())
    # every complete left frame goes in; the good ones whose right frame is complete come out,
    # the bad ones (bgr16, 320x240) are dropped
    readable = BagReader(cut)
    lefts = [m for _, m in readable.read("/stereo/left/image_raw")]
    n_rights = sum(1 for _ in readable.read("/stereo/right/image_raw"))
    good = [m.encoding == "bgr8" and m.width == 640 for m in lefts]
    assert result.frames_in == len(lefts) < 4
    assert result.frames_out == sum(good[:n_rights]) >= 1 and result.frames_dropped == good.count(False)


def test_run_keeps_recorded_timing(croton, tmp_path):
    """At rate 2 a 0.3 s bag takes about 0.15 s to play; remapped input topics."""
    bag, rig = croton
    reader = BagReader(bag)
    frames = [(convert.msg_to_image(lm), convert.msg_to_image(rm), 1_000_000_000 + k * 200_000_000,
               1_000_000_000 + k * 200_000_000 + 3_000_000)
              for k, ((_, lm), (_, rm)) in enumerate(zip(reader.read("/stereo/left/image_raw"),
                                                       reader.read("/stereo/right/image_raw")))]
    src = write_stereo_bag(tmp_path / "src.mcap", frames)
    remapped = tmp_path / "cam.mcap"
    from canopy_stereo.bag import BagWriter

    with BagWriter(remapped) as w:
        for m in BagReader(src).messages():
            w.write(m.topic.replace("/stereo/", "/cam/"), m.data, m.log_time_ns,
                    publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    # pairs 100 ms apart: on a loaded machine SGBM may still be busy when the next one comes, and the
    # camera default (one waiting pair, newest wins) would drop one as superseded; this test is about
    # the player's timing and remapping, so disparity_node keeps every pair waiting
    options = GraphOptions(matcher="sgbm", segment=False, parameter_services=False,
                           node_parameters={"disparity_node": {"waiting_pairs": 4}})
    result = run_bag(remapped, rig, rate=2.0, options=options, remap={
        "/cam/left/image_raw": "/stereo/left/image_raw", "/cam/right/image_raw": "/stereo/right/image_raw"})
    assert result.frames_out == 4
    # frames are 200 ms apart in the bag: at rate 2 the last is published >= 300 ms after the first
    assert result.wall_s >= 0.3


def test_shared_multithreaded_executor_runs_the_graph_too(croton):
    """``executor="multi"`` (one rclpy MultiThreadedExecutor) gives the same clouds; an
    unknown executor layout is refused by name."""
    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.ros.context import ros_context
    from canopy_stereo.ros.graph import CanopyGraph

    bag, rig = croton
    options = GraphOptions(matcher="sgbm", segment=False, parameter_services=False, executor="multi", threads=4)
    result = run_bag(bag, rig, rate=0, options=options, keep=("points2",))
    assert result.frames_out == 4 and result.frames_dropped == 0
    pts, _ = convert.cloud2_to_points(deserialize_message(result.outputs["points2"][0][1], PointCloud2))
    assert len(pts) > 100_000
    with ros_context() as ctx, pytest.raises(CanopyStereoError, match="unknown executor 'pool'"):
        CanopyGraph(rig, ctx, GraphOptions(executor="pool"))


def test_run_needs_the_input_topics(croton, tmp_path):
    """A bag under another namespace is played into the graph's when it has one raw stereo
    pair (stereo_input_remap); with two pairs it is ambiguous: refused, naming the topics."""
    from canopy_stereo.bag import BagReader, BagWriter
    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.ros.runner import stereo_input_remap

    bag, rig = croton
    topics = set(BagReader(bag).topics)
    assert stereo_input_remap(topics, namespace="/rig_a") == {
        "/stereo/left/image_raw": "/rig_a/left/image_raw", "/stereo/right/image_raw": "/rig_a/right/image_raw"}
    assert stereo_input_remap(topics, namespace="stereo") == {}
    two = tmp_path / "two_pairs.mcap"
    with BagWriter(two) as w:
        for m in BagReader(bag).messages():
            for ns in ("/cam1/", "/cam2/"):
                w.write(m.topic.replace("/stereo/", ns), m.data, m.log_time_ns,
                        publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    with pytest.raises(CanopyStereoError, match="no /other/left/image_raw .*topics: /cam1/left"):
        run_bag(two, rig, options=GraphOptions(namespace="/other", parameter_services=False))


def test_launch_file_names_only_existing_executables():
    src = (REPO / "setup.py").read_text()
    namespace = {}
    exec(src[src.index("ROS_EXECUTABLES"):src.index("CONSOLE_SCRIPTS")], namespace)
    executables = set(namespace["ROS_EXECUTABLES"])
    tree = ast.parse((REPO / "launch" / "canopy_stereo.launch.py").read_text())
    named = {kw.value.value for node in ast.walk(tree) if isinstance(node, ast.Call)
             for kw in node.keywords if kw.arg == "executable" and isinstance(kw.value, ast.Constant)}
    assert named and named <= executables
    assert {"camera_node", "rectify_node", "disparity_node", "segment_node", "point_cloud_node"} <= named
    packages = {kw.value.id if isinstance(kw.value, ast.Name) else kw.value.value
                for node in ast.walk(tree) if isinstance(node, ast.Call)
                for kw in node.keywords if kw.arg == "package"}
    assert packages == {"PACKAGE"}
    assert 'PACKAGE = "canopy_stereo"' in (REPO / "launch" / "canopy_stereo.launch.py").read_text()


def test_graph_from_cameras(croton, tmp_path):
    """camera_node x2 (image sequences standing in for webcams) -> the whole graph -> points2."""
    import cv2
    from rclpy.node import Node

    from canopy_stereo.ros.context import ros_context, wait_for
    from canopy_stereo.ros.graph import CanopyGraph
    from canopy_stereo.ros.qos import recording_qos

    bag, rig = croton
    reader = BagReader(bag)
    for side in ("left", "right"):
        for k, (_, m) in enumerate(reader.read(f"/stereo/{side}/image_raw")):
            cv2.imwrite(str(tmp_path / f"{side}_{k:03d}.png"), convert.msg_to_image(m))
    fps = 5.0
    options = GraphOptions(matcher="sgbm", segment=False, parameter_services=False,
                           node_parameters={"rectify_node": {"sync_slop": 0.5 / fps}})
    cams = [{"device": str(tmp_path / f"{side}_%03d.png"), "fps": fps} for side in ("left", "right")]
    with ros_context() as ctx:
        graph = CanopyGraph(rig, ctx, options, cameras=cams)
        sink = Node("sink", context=ctx, namespace="/stereo", start_parameter_services=False)
        clouds = []
        sink.create_subscription(PointCloud2, "points2", clouds.append, recording_qos())
        from sensor_msgs.msg import CameraInfo

        infos = []  # the camera nodes publish their camera_info like a driver
        sink.create_subscription(CameraInfo, "right/camera_info", infos.append, recording_qos())
        graph.add_node(sink)
        graph.spin_in_background()
        try:
            assert wait_for(lambda: len(clouds) >= 2 and infos, 30.0)
        finally:
            graph.shutdown()
            sink.destroy_node()
    assert infos[0].header.frame_id == "left_camera_optical_frame" and infos[0].p[3] < 0  # one frame per pair
    pts, _ = convert.cloud2_to_points(clouds[0])
    # the croton and its backdrop lie 0.5 to 1.1 m in front of the paper's rig
    z = np.median(pts[:, 2])
    assert 0.5 < z < 1.1 and len(pts) > 100_000


@pytest.mark.slow
def test_node_processes_tune_the_allocator_unless_the_environment_does():
    import os
    import subprocess
    import sys

    code = "from canopy_stereo.ros.context import tune_memory_allocator as t; print(t(), t())"
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["True", "True"]  # glibc: applied (and idempotent)
    env["MALLOC_MMAP_THRESHOLD_"] = "1048576"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]  # the user's own setting wins


@pytest.mark.slow
def test_node_processes_use_one_opencv_thread_unless_the_environment_says():
    import os
    import subprocess
    import sys

    code = ("import cv2; from canopy_stereo.ros.context import tune_opencv_threads as t; "
            "print(t(), cv2.getNumThreads())")
    env = {k: v for k, v in os.environ.items() if k != "CANOPY_STEREO_OPENCV_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"]
    env["CANOPY_STEREO_OPENCV_THREADS"] = "0"  # OpenCV's own pool: one thread per core
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split()[0] == "0" and int(out.stdout.split()[1]) == os.cpu_count()
    env["CANOPY_STEREO_OPENCV_THREADS"] = "many"  # named, and the default kept
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"]
    assert "CANOPY_STEREO_OPENCV_THREADS must be an integer >= 0, got 'many'" in out.stderr
