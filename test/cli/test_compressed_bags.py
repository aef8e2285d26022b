"""Robot bags usually hold only compressed images: ``run``, ``batch`` and ``view`` read a bag
whose stereo frames are JPEG ``CompressedImage`` on image_transport's
``/stereo/{left,right}/image_raw/compressed``, and ``run --record --compress-images`` stores
its image outputs compressed. The same croton frames as a raw bag are the reference."""
import csv
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.io.compressed_image import COMPRESSED_IMAGE_TYPE  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig, write_stereo_bag  # noqa: E402
from canopy_stereo.ros.convert import msg_to_image, stamp_to_ns  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """``raw.mcap`` and ``jpeg.mcap`` (quality 95, compressed topics only) of the bundled croton
    frames, both with the rig and plant metadata, in one folder."""
    folder = tmp_path_factory.mktemp("compressed_bags")
    src = BagReader(bundled_bag("croton"))
    lefts = [(stamp_to_ns(m.header.stamp), msg_to_image(m).copy()) for _, m in src.read("/stereo/left/image_raw")]
    rights = [(stamp_to_ns(m.header.stamp), msg_to_image(m).copy()) for _, m in src.read("/stereo/right/image_raw")]
    frames = [(left, right, tl, tr) for (tl, left), (tr, right) in zip(lefts, rights)]
    rig = load_rig(bundled_rig("croton"))
    out = {}
    for name, fmt in (("raw", "raw"), ("jpeg", "jpeg")):
        out[name] = write_stereo_bag(folder / f"{name}.mcap", frames, rig=rig, image_format=fmt, jpeg_quality=95,
                                     metadata={"plant_id": f"croton_{name}"})
    return folder, out


def _cli(*args, timeout=600):
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.run([sys.executable, "-m", "canopy_stereo.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=env)


def _median_depths(path) -> dict:
    bag = BagReader(path)
    return {stamp_to_ns(m.header.stamp): float(np.nanmedian(np.where(msg_to_image(m) > 0, msg_to_image(m), np.nan)))
            for _, m in bag.read("/stereo/left/depth")}


def test_the_compressed_bag_holds_only_compressed_images(bags):
    _, paths = bags
    topics = BagReader(paths["jpeg"]).topics
    assert {t: i.type_name for t, i in topics.items()} == {
        "/stereo/left/image_raw/compressed": COMPRESSED_IMAGE_TYPE,
        "/stereo/right/image_raw/compressed": COMPRESSED_IMAGE_TYPE}
    assert paths["jpeg"].stat().st_size < paths["raw"].stat().st_size / 3


def test_run_on_compressed_images_matches_the_raw_bag_and_records_compressed(bags, cli, tmp_path):
    _, paths = bags
    rig = bundled_rig("croton")
    rec = {}
    for name in ("raw", "jpeg"):
        rec[name] = tmp_path / f"out_{name}.mcap"
        extra = ["--compress-images"] if name == "jpeg" else []
        code, stdout, stderr = cli("run", "--bag", paths[name], "--rig", rig, "--rate", "0", "--record",
                                   rec[name], *extra)
        assert code == 0, stderr
        assert "frames in: 4, frames out: 4" in stdout, stdout
    raw, jpeg = _median_depths(rec["raw"]), _median_depths(rec["jpeg"])
    assert sorted(raw) == sorted(jpeg) and len(raw) == 4
    rel = max(abs(jpeg[s] - raw[s]) / raw[s] for s in raw)
    assert rel <= 0.001, rel  # median depth within 0.1 % of the raw path at quality 95
    topics = BagReader(rec["jpeg"]).topics
    assert topics["/stereo/left/mask/compressed"].type_name == COMPRESSED_IMAGE_TYPE  # PNG: labels stay exact
    assert "/stereo/left/mask" not in topics and topics["/stereo/left/depth"].message_count == 4  # 32FC1: raw
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CompressedImage, Image

    from canopy_stereo.io.image_codec import decode_compressed

    raw_masks = {stamp_to_ns(m.header.stamp): msg_to_image(m)
                 for _, m in BagReader(rec["raw"]).read("/stereo/left/mask")}
    for m in BagReader(rec["jpeg"]).messages(["/stereo/left/mask/compressed"]):
        msg = deserialize_message(m.data, CompressedImage)
        assert msg.format == "mono8; png compressed mono8"
        mask = decode_compressed(msg.data, msg.format, grey=True)
        assert set(np.unique(mask)) <= {0, 255} and mask.shape == (480, 640)
    assert raw_masks and Image  # the raw run recorded its masks raw


def test_batch_measures_a_compressed_bag_like_the_raw_one(bags, tmp_path):
    folder, _ = bags
    out = tmp_path / "traits"
    res = _cli("batch", folder, "-o", out, "--workers", "1", "--max-frames", "1")
    assert res.returncode == 0, res.stderr[-3000:]
    with open(out / "plants.csv", newline="") as f:
        rows: dict[str, dict] = {}
        for r in csv.DictReader(f):  # one row per plant: each bag's croton is its largest plant
            old = rows.get(r["plant_id"])
            if old is None or float(r["hull_volume_cm3"] or 0) > float(old["hull_volume_cm3"] or 0):
                rows[r["plant_id"]] = r
    raw, jpeg = rows["croton_raw"], rows["croton_jpeg"]
    assert int(jpeg["frames"]) == int(raw["frames"]) == 1 and jpeg["rig"] == "bag"
    # height within 1 % and width within 2 % of what the raw frames give (extents hang on the
    # automatic mask's outermost pixels at leaf edges, where JPEG's ringing lands: the shape-based
    # plant mask moves the width by 1.7 % at quality 95; canopy depth, the extent along the view,
    # hangs on a few far-edge pixels and is not compared)
    for trait, rel in (("canopy_height_mm", 0.01), ("canopy_width_mm", 0.02)):
        assert float(jpeg[trait]) == pytest.approx(float(raw[trait]), rel=rel), trait


def test_view_runs_a_compressed_bag_through_the_graph(bags, tmp_path):
    pytest.importorskip("rerun")
    _, paths = bags
    out = tmp_path / "jpeg.rrd"
    res = _cli("view", paths["jpeg"], "--rig", bundled_rig("croton"), "--save", out, "--no-measure")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "4 frames through the graph, 4 shown" in res.stdout, res.stdout
    assert out.stat().st_size > 100_000


def test_bag_compress_and_demo_on_compressed_bags(cli, tmp_path):
    """``bag compress`` stores the stereo frames as JPEG on /compressed (the 16UC1 truth stays
    raw); ``demo --compressed`` replays the croton that way and still meets its depth truth."""
    out = tmp_path / "croton_jpeg.mcap"
    code, stdout, stderr = cli("bag", "compress", bundled_bag("croton"), "-o", out, "--jpeg-quality", "90")
    assert code == 0, stderr
    types = {t: i.type_name for t, i in BagReader(out).topics.items()}
    assert types == {"/stereo/left/image_raw/compressed": COMPRESSED_IMAGE_TYPE,
                     "/stereo/right/image_raw/compressed": COMPRESSED_IMAGE_TYPE,
                     "/truth/left/depth": "sensor_msgs/msg/Image"}, types
    assert out.stat().st_size < bundled_bag("croton").stat().st_size / 3
    code, _, stderr = cli("bag", "compress", bundled_bag("croton"), "-o", out)
    assert code == 2 and "exists" in stderr
    code, stdout, stderr = cli("demo", "--scene", "croton", "--compressed", "--out", tmp_path / "demo")
    assert code == 0, stderr
    assert "croton_compressed.mcap" in stdout and "frames out: 4" in stdout, stdout
