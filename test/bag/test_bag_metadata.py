"""Self-describing bags: ``bag_record --metadata ... --rig ...`` and the metadata records."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from canopy_stereo.bag.metadata import (
    METADATA_RECORD,
    RIG_RECORD,
    canopy_metadata,
    matches_selection,
    parse_key_values,
    parse_selection,
)
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.rig import load_rig, rig_to_yaml

REPO = Path(__file__).resolve().parents[2]
T0 = 1_700_000_000_000_000_000


def test_key_values_and_selection():
    assert parse_key_values(["plant_id=A12", "plot= row1 ", "note=a=b", "date=2026-05-04"]) == {
        "plant_id": "A12", "plot": "row1", "note": "a=b", "date": "2026-05-04"}
    for bad in (["plant_id"], ["=x"], ["1abc=x"], ["a b=x"]):
        with pytest.raises(CanopyStereoError, match="--metadata"):
            parse_key_values(bad)
    sel = parse_selection(["plot=row1", "plot=row2", "treatment=dry"])
    assert sel == {"plot": {"row1", "row2"}, "treatment": {"dry"}}
    assert matches_selection({"plot": "row2", "treatment": "dry", "x": "1"}, sel)
    assert not matches_selection({"plot": "row3", "treatment": "dry"}, sel)
    assert not matches_selection({"plot": "row1"}, sel)  # a key the bag lacks does not match


def test_writer_records_survive_truncation_and_rosbags_reads_the_bag(tmp_path):
    pytest.importorskip("rclpy")
    from canopy_stereo.bag import BagError, BagReader, BagWriter
    from canopy_stereo.ros import convert

    rig = load_rig(REPO / "config" / "croton_rig.yaml")
    path = tmp_path / "m.mcap"
    with BagWriter(path, chunk_size=1 << 12, metadata={METADATA_RECORD: {"plant_id": "A", "n": 3}}) as bag:
        for k in range(20):
            bag.write("/stereo/left/image_raw", convert.image_to_msg(
                np.random.default_rng(k).integers(0, 255, (32, 32, 3), dtype=np.uint8)), T0 + k)
        bag.add_metadata(RIG_RECORD, {"yaml": rig_to_yaml(rig)})
        with pytest.raises(BagError, match="reserved"):
            bag.add_metadata("rosbag2", {})
    full = BagReader(path)
    records = full.metadata()
    assert set(records) == {METADATA_RECORD, RIG_RECORD, "rosbag2"}
    meta, got_rig = canopy_metadata(records)
    assert meta == {"plant_id": "A", "n": "3"}
    np.testing.assert_array_equal(got_rig.P_right, rig.P_right)
    assert got_rig.extra == rig.extra
    # rosbag2's own custom_data (ros2 bag record --custom-data) holds the same pairs ...
    info = yaml.safe_load(records["rosbag2"]["serialized_metadata"])
    assert info["custom_data"] == {"plant_id": "A", "n": "3"}
    # ... and a bag that has only custom_data (recorded by ros2 bag record) is read too
    only = tmp_path / "ros2.mcap"
    with BagWriter(only) as bag:
        bag.custom_data.update({"plant_id": "Z9", "date": "2026-06-01"})
        bag.write("/stereo/left/image_raw", convert.image_to_msg(np.zeros((4, 4, 3), np.uint8)), T0)
    assert canopy_metadata(BagReader(only).metadata()) == ({"plant_id": "Z9", "date": "2026-06-01"}, None)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    part = BagReader(cut)
    assert part.truncated and part.metadata() == {METADATA_RECORD: {"plant_id": "A", "n": "3"}}
    rosbags = pytest.importorskip("rosbags.highlevel")
    with rosbags.AnyReader([path]) as reader:  # the standard reader ignores our records
        assert sum(1 for _ in reader.messages()) == 20
    with pytest.raises(CanopyStereoError, match="rig record"):
        canopy_metadata({RIG_RECORD: {"yaml": "not: [a rig"}}, source="x.mcap")


@pytest.mark.slow
@pytest.mark.ros
def test_bag_record_writes_metadata_and_rig(tmp_path):
    pytest.importorskip("rclpy")
    from rclpy.node import Node
    from sensor_msgs.msg import Image

    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros import convert
    from canopy_stereo.ros.context import private_domain_id, ros_context, wait_for
    from canopy_stereo.ros.qos import publisher_qos
    from test.support.ros_harness import killed_at_exit

    out = tmp_path / "rec.mcap"
    domain = private_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = "import sys; from canopy_stereo.ros.recorder import main; sys.exit(main())"
    rig_file = REPO / "config" / "croton_rig.yaml"
    proc = subprocess.Popen([sys.executable, "-c", code, "-o", str(out), "/meta_test/left",
                             "--metadata", "plant_id=A12", "plot=row1", "date=2026-05-04",
                             "--rig", str(rig_file)], env=env, stderr=subprocess.PIPE, text=True)
    with killed_at_exit(proc):
        with ros_context(domain) as ctx:
            node = Node("meta_test_pub", context=ctx, start_parameter_services=False)
            pub = node.create_publisher(Image, "/meta_test/left", publisher_qos("reliable", 10))
            assert wait_for(lambda: pub.get_subscription_count() >= 1, 30.0), "recorder did not subscribe"
            time.sleep(0.2)
            for k in range(3):
                pub.publish(convert.image_to_msg(np.full((4, 4, 3), k, np.uint8), "bgr8", stamp_ns=T0 + k))
                time.sleep(0.05)
            time.sleep(0.5)
            node.destroy_node()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    bag = BagReader(out)
    assert bag.topics["/meta_test/left"].message_count == 3
    meta, rig = canopy_metadata(bag.metadata())
    assert meta == {"plant_id": "A12", "plot": "row1", "date": "2026-05-04"}
    np.testing.assert_array_equal(rig.P_left, load_rig(rig_file).P_left)
    assert rig.extra == load_rig(rig_file).extra

    bad = subprocess.run([sys.executable, "-c", code, "-o", str(tmp_path / "x.mcap"), "/t",
                          "--metadata", "plant_id"], env=env, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "KEY=VALUE" in bad.stderr


@pytest.mark.slow
@pytest.mark.ros
def test_graph_recording_from_cameras_is_measured_without_a_rig(tmp_path):
    """canopy_graph --cameras ... --record --metadata (its own process) -> a self-describing bag
    -> one batch row with the recording's metadata, no --rig."""
    pytest.importorskip("rclpy")
    import cv2

    from canopy_stereo.bag import BagReader
    from canopy_stereo.batch.work import BatchOptions, process_bag
    from canopy_stereo.ros.bundled import bundled_bag, bundled_rig
    from canopy_stereo.ros.context import private_domain_id
    from canopy_stereo.ros.convert import msg_to_image
    from test.support.ros_harness import killed_at_exit

    src = BagReader(bundled_bag("croton"))
    for side in ("left", "right"):
        for k, (_, m) in enumerate(src.read(f"/stereo/{side}/image_raw")):
            cv2.imwrite(str(tmp_path / f"{side}_{k:03d}.png"), msg_to_image(m))
    out = tmp_path / "rec.mcap"
    env = dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = "import sys; from canopy_stereo.ros.canopy_graph import main; sys.exit(main())"
    fps = 4.0
    proc = subprocess.Popen([sys.executable, "-c", code, "--rig", str(bundled_rig("croton")),
                             "--cameras", str(tmp_path / "left_%03d.png"), str(tmp_path / "right_%03d.png"),
                             "--fps", str(fps), "--matcher", "sgbm", "--no-segment", "--record", str(out),
                             "--metadata", "plant_id=C1", "treatment=control", "date=2026-05-04"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with killed_at_exit(proc):
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and proc.poll() is None:
            if out.is_file() and out.stat().st_size > 3_000_000:  # a few raw pairs flushed
                break
            time.sleep(0.25)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    rows = process_bag(out, BatchOptions(max_frames=1, sync_slop_s=0.5 / fps, matcher="sgbm"))
    # one row per plant the pipeline numbers; the croton is the largest (a stray fragment may be numbered too)
    assert len({str(r["metadata"]) for r in rows}) == 1
    row = max(rows, key=lambda r: r["hull_volume_cm3"] or 0)
    assert row["metadata"] == {"plant_id": "C1", "treatment": "control", "date": "2026-05-04"}
    assert row["rig"] == "bag" and row["frames"] == 1
    # the croton stands about 45 cm tall (bundled bag's scene)
    assert 300 < row["canopy_height_mm"] < 600
