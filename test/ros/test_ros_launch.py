"""The launch file, evaluated as ``ros2 launch`` does (test/support/launch_eval.py: launch and
launch_ros are not on PyPI) and its nodes started as processes: bag mode and camera mode
(image sequences standing in for webcams) both produce clouds; ``canopy_graph --loop``
replays a bag through one graph without rebuilding it."""
import re
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402

from canopy_stereo.ros import convert  # noqa: E402
from test.conftest import REPO  # noqa: E402
from test.support.launch_eval import evaluate  # noqa: E402
from test.support.ros_harness import Probe, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

CROTON_BAG = REPO / "bags" / "croton.mcap"
CROTON_RIG = REPO / "config" / "croton_rig.yaml"


def _check_cloud(data: bytes):
    pts, _ = convert.cloud2_to_points(deserialize_message(data, PointCloud2))
    z = float(np.median(pts[:, 2]))
    assert len(pts) > 100_000 and 0.5 < z < 1.1  # the croton 0.5-1.1 m in front of the rig


def test_launch_file_evaluates_to_one_process_per_node():
    cmds, declared = evaluate({"bag": str(CROTON_BAG), "rig": str(CROTON_RIG), "loop": "true"})
    assert [c.executable for c in cmds] == ["bag_play", "rectify_node", "disparity_node", "segment_node",
                                            "point_cloud_node"]
    play = cmds[0]
    assert play.arguments[:3] == [str(CROTON_BAG), "--rate", "1.0"] and "--loop" in play.arguments
    rect = cmds[1]
    assert rect.parameters == {"fps": 0.0,  # from a bag: measured from the stamps
                               "frame_prefix": "", "parent_frame": "", "mount": "", "camera_mount": "",
                               "publish_tf": True}  # not mounted: the rig's world frame is a root
    assert ["-r", "__ns:=/stereo"] == rect.ros_args[:2] and str(CROTON_RIG) in rect.ros_args
    cmds, _ = evaluate({"left_device": "0", "right_device": "2", "fps": "10"})
    assert [c.executable for c in cmds] == ["camera_node", "camera_node", "rectify_node", "disparity_node",
                                            "segment_node", "point_cloud_node"]
    assert cmds[0].parameters == {"camera_name": "left", "device": 0, "fps": 10,  # integer fps, as launch_ros
                                  "frame_id": "left_camera_optical_frame"}
    assert cmds[2].parameters["fps"] == 10.0  # pairing tolerance from the camera rate
    assert cmds[3].parameters == {"matcher": "elas", "elas.subsampling": False, "roi": False}
    assert cmds[4].parameters == {"queue_size": 1, "follow_disparity": False,  # no mask used: the newest image
                                  "depth_cue": False}
    assert set(declared) >= {"rig", "namespace", "left_device", "right_device", "fps", "matcher", "use_mask",
                             "segment_depth_cue", "elas_subsampling", "bag", "rate", "loop"}
    cmds, _ = evaluate({"elas_subsampling": "true", "segment_depth_cue": "true"})
    assert cmds[3].parameters["elas.subsampling"] is True and cmds[4].parameters["depth_cue"] is True
    cmds, _ = evaluate({"use_mask": "true"})  # masked clouds: disparity only where the plant was
    assert cmds[3].parameters["roi"] is True and cmds[5].parameters["use_mask"] is True
    assert cmds[4].parameters["follow_disparity"] is True and cmds[4].parameters["queue_size"] == 5


def _clouds(ros_processes, commands, want: int, timeout_s: float):
    probe = Probe(ros_processes.domain_id)
    try:
        clouds = probe.subscribe(PointCloud2, "points2")
        ros_processes.start_launched(commands)
        ok = wait_for(lambda: len(clouds) >= want, timeout_s, group=ros_processes)
        assert ok, (len(clouds), ros_processes.logs())
        with clouds.lock:
            return list(clouds.items)
    finally:
        probe.close()


def test_launch_bag_mode_produces_clouds_and_loops(ros_processes):
    """``bag:=croton.mcap loop:=true``: the 4-frame bag plays again and again; the nodes
    follow its stamps jumping back, so clouds keep coming (more than one pass)."""
    cmds, _ = evaluate({"bag": str(CROTON_BAG), "rig": str(CROTON_RIG), "loop": "true", "matcher": "sgbm"},
                       param_dir=ros_processes.log_dir)
    items = _clouds(ros_processes, cmds, want=10, timeout_s=180.0)
    stamps = [s for _, s, _ in items]
    assert len(set(stamps)) <= 4 and len(stamps) > len(set(stamps))  # the same frames, again and again
    _check_cloud(items[-1][2])


def test_launch_camera_mode_with_image_sequences_produces_clouds(ros_processes, tmp_path):
    import cv2

    from canopy_stereo.bag import BagReader

    reader = BagReader(CROTON_BAG)
    for side in ("left", "right"):
        for k, (_, m) in enumerate(reader.read(f"/stereo/{side}/image_raw")):
            cv2.imwrite(str(tmp_path / f"{side}_{k:03d}.png"), convert.msg_to_image(m))
    cmds, _ = evaluate({"rig": str(CROTON_RIG), "left_device": str(tmp_path / "left_%03d.png"),
                        "right_device": str(tmp_path / "right_%03d.png"), "fps": "5", "matcher": "sgbm"},
                       param_dir=ros_processes.log_dir)
    items = _clouds(ros_processes, cmds, want=3, timeout_s=180.0)
    _check_cloud(items[-1][2])
    log = next(p for p in ros_processes.processes if p.name == "rectify_node").log()
    assert "sync slop 0.1 s" in log  # half a period at 5 frames/s


def test_canopy_graph_loop_replays_without_rebuilding(ros_processes):
    """``canopy_graph --bag croton.mcap --loop``: one graph, clouds from several passes, a
    summary on Ctrl-C."""
    probe = Probe(ros_processes.domain_id)
    try:
        clouds = probe.subscribe(PointCloud2, "points2")
        proc = ros_processes.start("canopy_graph", "--rig", CROTON_RIG, "--bag", CROTON_BAG, "--loop",
                                   "--matcher", "sgbm", "--no-segment")
        assert wait_for(lambda: len(clouds) >= 10, 180.0, group=ros_processes), ros_processes.logs()
        stamps = clouds.stamps()
        time.sleep(0.5)
        code = proc.stop()
    finally:
        probe.close()
    log = proc.log()
    assert code == 0, log
    assert log.count("rectifying 640x480 pairs") == 1  # the nodes were built once
    # 10 clouds of a 4-frame bag: several passes, each stamp again and again
    assert len(set(stamps)) <= 4 and len(stamps) >= 10
    # the final summary ("frames in: X, frames out: Y, dropped: Z"), not the per-pass lines
    # ("frames in: X, frames out: Y (after pass N)") printed before it
    counts = [tuple(map(int, m.groups())) for m in re.finditer(
        r"^frames in: (\d+), frames out: (\d+)(?!\d| \(after pass)", log, re.MULTILINE)]
    assert counts, log
    frames_in, frames_out = counts[-1]
    assert frames_in >= 10 and frames_in >= frames_out >= 5, log
    passes = [tuple(map(int, m.groups())) for m in re.finditer(
        r"^frames in: (\d+), frames out: (\d+) \(after pass \d+\)", log, re.MULTILINE)]
    assert len(passes) >= 2 and all(i <= frames_in and o <= frames_out for i, o in passes), log


def test_launch_two_mounted_rigs_side_by_side(ros_processes):
    """Two launches (namespace + frame_prefix + parent_frame + mount) evaluate to nodes that
    never share a name, and their rectify_nodes (processes of their own, one DDS domain)
    put each rig under base_link by its own mount, every frame prefixed."""
    from std_msgs.msg import String

    from canopy_stereo.geometry.frames import pose_matrix
    from canopy_stereo.ros.stereo_geometry import parse_stereo_geometry
    from canopy_stereo.ros.tf import latched_qos

    mounts = {"rig_a": [0.4, 0.25, 1.1, 0.0, 0.0, 0.25881904510252074, 0.9659258262890683],
              "rig_b": [0.4, -0.25, 0.95, 0.0, 0.0, 0.0, 1.0]}
    launched = {}
    for ns, mount in mounts.items():
        cmds, _ = evaluate({"bag": str(CROTON_BAG), "rig": str(CROTON_RIG), "namespace": ns,
                            "frame_prefix": f"{ns}/", "parent_frame": "base_link", "mount": str(mount)})
        launched[ns] = {c.executable: c for c in cmds}
        rect = launched[ns]["rectify_node"]
        assert rect.parameters["mount"] == mount and rect.parameters["frame_prefix"] == f"{ns}/"
        assert f"/stereo/left/image_raw:=/{ns}/left/image_raw" in launched[ns]["bag_play"].arguments
    # every node (the bag player's too) lives in its rig's namespace: no name twice
    names = [(c.name or c.executable, next(a for a in c.ros_args if a.startswith("__ns:=")))
             for cmds in launched.values() for c in cmds.values()]
    assert len(names) == len(set(names))
    probe = Probe(ros_processes.domain_id, namespace="/")
    try:
        got = {ns: [] for ns in mounts}
        for ns in mounts:
            probe.node.create_subscription(String, f"/{ns}/stereo_geometry", got[ns].append, latched_qos())
        ros_processes.start_launched([launched[ns]["rectify_node"] for ns in mounts])
        assert wait_for(lambda: all(got.values()), 60.0, group=ros_processes), ros_processes.logs()
    finally:
        probe.close()
    for ns, mount in mounts.items():
        g = parse_stereo_geometry(got[ns][0])
        assert g.world_frame == f"{ns}/canopy_world" and g.frames["parent"] == "base_link"
        assert all(v.startswith(f"{ns}/") for k, v in g.frames.items() if v and k != "parent")
        np.testing.assert_allclose(g.lookup("base_link", f"{ns}/canopy_world"), pose_matrix(mount), atol=1e-12)
