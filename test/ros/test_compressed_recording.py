"""Recording images compressed (``bag_record --compress-images``, shared by ``run --record`` and
``canopy_graph --record``): camera images become JPEG and masks PNG on image_transport's
``<topic>/compressed``, depth stays raw, and rosbags (a tool users have) reads the result."""
import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")

from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.bag import BagReader, BagWriter  # noqa: E402
from canopy_stereo.io.compressed_image import COMPRESSED_IMAGE_TYPE  # noqa: E402
from canopy_stereo.io.image_codec import decode_compressed  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.compressed import RecordingCompression  # noqa: E402
from canopy_stereo.ros.context import wait_for  # noqa: E402
from test.support.nodes import TIMEOUT  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_recorder_stores_images_compressed_masks_lossless_depth_raw(harness, tmp_path):
    from canopy_stereo.ros.recorder import BagRecorder

    rng = np.random.default_rng(3)
    colour = cv2.GaussianBlur(rng.integers(0, 255, (120, 160, 3), dtype=np.uint8), (9, 9), 3)
    mask = np.where(rng.random((120, 160)) > 0.5, 255, 0).astype(np.uint8)
    depth = rng.uniform(0.4, 1.2, (120, 160)).astype(np.float32)
    topics = {"/stereo/left/image_raw": (colour, "bgr8"), "/stereo/left/mask": (mask, "mono8"),
              "/stereo/left/depth": (depth, "32FC1")}
    out = tmp_path / "rec.mcap"
    pubs = {t: harness.publisher(Image, t) for t in topics}
    recorder = harness.add(BagRecorder(BagWriter(out), list(topics), context=harness.ctx,
                                       compression=RecordingCompression(quality=90)))
    assert wait_for(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), TIMEOUT)
    for k in range(3):
        for t, (img, enc) in topics.items():
            pubs[t].publish(convert.image_to_msg(img, enc, stamp_ns=1_000 + k, frame_id="left"))
    assert wait_for(lambda: sum(recorder.received.values()) == 9, TIMEOUT), recorder.received
    harness.remove(recorder)
    recorder.close()
    recorder.destroy_node()
    bag = BagReader(out)
    assert {t: (i.type_name, i.message_count) for t, i in bag.topics.items() if t.startswith("/stereo")} == {
        "/stereo/left/image_raw/compressed": (COMPRESSED_IMAGE_TYPE, 3),
        "/stereo/left/mask/compressed": (COMPRESSED_IMAGE_TYPE, 3),
        "/stereo/left/depth": ("sensor_msgs/msg/Image", 3)}
    from rosbags.highlevel import AnyReader  # what users read bags with, outside ROS

    with AnyReader([out]) as reader:
        got = {}
        for conn, _, raw in reader.messages():
            if conn.topic.startswith("/stereo"):
                got.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    jpeg = got["/stereo/left/image_raw/compressed"][0]
    assert jpeg.format == "bgr8; jpeg compressed bgr8" and jpeg.header.frame_id == "left"
    assert [m.header.stamp.nanosec for m in got["/stereo/left/image_raw/compressed"]] == [1000, 1001, 1002]
    back = decode_compressed(bytes(jpeg.data), jpeg.format)
    assert np.abs(back.astype(int) - colour).mean() < 3  # JPEG 90
    png = got["/stereo/left/mask/compressed"][0]
    assert png.format == "mono8; png compressed mono8"
    assert np.array_equal(decode_compressed(bytes(png.data), png.format, grey=True), mask)  # labels exact
    assert got["/stereo/left/depth"][0].encoding == "32FC1"


def test_canopy_graph_records_the_cameras_jpeg_and_batch_measures_it(tmp_path):
    """``canopy_graph --cameras L R --record OUT --compress-images``: the cameras publish JPEG too and
    the recording holds it (no raw frames); ``batch``'s reader measures that bag."""
    import time

    from canopy_stereo.batch.work import BatchOptions, process_bag
    from canopy_stereo.ros.bundled import bundled_bag, bundled_rig
    from canopy_stereo.ros.context import private_domain_id
    from test.support.ros_harness import ProcessGroup

    for side in ("left", "right"):
        for k, (_, m) in enumerate(BagReader(bundled_bag("croton")).read(f"/stereo/{side}/image_raw")):
            cv2.imwrite(str(tmp_path / f"{side}_{k:03d}.png"), convert.msg_to_image(m))
    out, fps = tmp_path / "rec.mcap", 4.0
    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    graph = group.start("canopy_graph", "--rig", bundled_rig("croton"), "--cameras", tmp_path / "left_%03d.png",
                        tmp_path / "right_%03d.png", "--fps", fps, "--matcher", "sgbm", "--record", out,
                        "--compress-images", "--metadata", "plant_id=C2")
    try:
        deadline, flushed_at = time.monotonic() + 120, None
        while time.monotonic() < deadline and graph.alive():
            # a few JPEG pairs flushed and the mask topic recorded for a few frames (the first masks
            # come after the segmentation's first cut)
            if (flushed_at is None and "recording /stereo/left/mask" in graph.log() and out.is_file()
                    and out.stat().st_size > 1_500_000):
                flushed_at = time.monotonic()
            if flushed_at is not None and time.monotonic() - flushed_at > 4.0 / fps:
                break
            time.sleep(0.25)
    finally:
        code = graph.stop(timeout_s=60)  # SIGINT: the recording is closed validly
    assert code == 0, graph.log()[-3000:]
    topics = BagReader(out).topics
    for side in ("left", "right"):
        assert topics[f"/stereo/{side}/image_raw/compressed"].type_name == COMPRESSED_IMAGE_TYPE
        assert f"/stereo/{side}/image_raw" not in topics
    assert topics["/stereo/left/mask/compressed"].type_name == COMPRESSED_IMAGE_TYPE
    rows = process_bag(out, BatchOptions(max_frames=1, sync_slop_s=0.5 / fps, matcher="sgbm"))
    row = max(rows, key=lambda r: r["hull_volume_cm3"] or 0)  # the croton: the largest plant row
    assert row["metadata"]["plant_id"] == "C2" and row["frames"] == 1
    assert 300 < row["canopy_height_mm"] < 600  # the croton stands about 45 cm tall
