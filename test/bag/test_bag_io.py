"""MCAP bag writer/reader: round trip with our reader and rosbags, truncation, schemas."""
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("mcap")

from rclpy.serialization import serialize_message  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.bag import (  # noqa: E402
    BagError,
    BagReader,
    BagWriter,
    msgdefs,  # noqa: E402
)
from canopy_stereo.ros import convert  # noqa: E402

pytestmark = pytest.mark.ros

T0 = 1_700_000_000_000_000_000


def _messages(n=4):
    rng = np.random.default_rng(3)
    K = np.array([[600.0, 0, 31.5], [0, 600.0, 23.5], [0, 0, 1]])
    out = []
    for k in range(n):
        stamp = T0 + k * 33_000_000
        img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        out.append(("/stereo/left/image_raw", convert.image_to_msg(img, "bgr8", stamp_ns=stamp,
                                                                   frame_id="left"), stamp))
        d = rng.uniform(-1, 40, (48, 64)).astype(np.float32)
        out.append(("/stereo/disparity",
                    convert.disparity_to_msg(d, 600.0, 0.03125, 0, 48, delta_d=1 / 16, stamp_ns=stamp,
                                             frame_id="rect"), stamp + 1000))
        pts = rng.normal(size=(48, 64, 3)).astype(np.float32)
        out.append(("/stereo/points2", convert.points_to_cloud2(pts, img[..., ::-1], stamp_ns=stamp),
                    stamp + 2000))
        out.append(("/stereo/left/camera_info",
                    convert.rectified_camera_info(K, (64, 48), 0.03, "left", stamp_ns=stamp,
                                                  frame_id="rect"), stamp + 3000))
    return out


def _write(path, messages, **kw):
    """Write the messages; returns the path and the exact CDR bytes stored.

    (CDR padding bytes are not zeroed by the serializer, so two serializations
    of one message may differ there: compare against the bytes written.)
    """
    stored = []
    with BagWriter(path, **kw) as bag:
        for topic, msg, t in messages:
            raw = serialize_message(msg)
            stored.append(raw)
            bag.write(topic, raw, t, publish_time_ns=convert.stamp_to_ns(msg.header.stamp),
                      msg_type=msgdefs.type_name(msg))
    return path, stored


def test_round_trip_our_reader_is_byte_identical(tmp_path):
    msgs = _messages()
    path, stored = _write(tmp_path / "rt.mcap", msgs)
    bag = BagReader(path)
    assert not bag.truncated and bag.message_count == len(msgs)
    assert bag.topics["/stereo/points2"].type_name == "sensor_msgs/msg/PointCloud2"
    assert bag.topics["/stereo/disparity"].message_count == 4
    assert bag.start_ns == msgs[0][2] and bag.end_ns == msgs[-1][2]
    got = list(bag.read())
    assert len(got) == len(msgs)
    for (topic, msg, t), raw, (rec, decoded) in zip(msgs, stored, got):
        assert rec.topic == topic and rec.log_time_ns == t
        assert rec.publish_time_ns == convert.stamp_to_ns(msg.header.stamp)
        assert rec.data == raw
        assert decoded == msg


def test_round_trip_with_rosbags(tmp_path):
    rosbags = pytest.importorskip("rosbags.highlevel")
    msgs = _messages(3)
    path, stored = _write(tmp_path / "rb.mcap", msgs, compression="lz4")
    with rosbags.AnyReader([Path(path)]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {
            "/stereo/left/image_raw": 3, "/stereo/disparity": 3, "/stereo/points2": 3,
            "/stereo/left/camera_info": 3}
        assert {c.topic: c.msgtype for c in reader.connections}["/stereo/disparity"] == \
            "stereo_msgs/msg/DisparityImage"
        got = [(c.topic, t, reader.deserialize(raw, c.msgtype), raw)
               for c, t, raw in reader.messages()]
    assert len(got) == len(msgs)
    for (topic, msg, t), written, (rtopic, rt, rmsg, raw) in zip(msgs, stored, got):
        assert (rtopic, rt) == (topic, t)
        assert bytes(raw) == written
        if isinstance(msg, Image):
            np.testing.assert_array_equal(rmsg.data, np.frombuffer(msg.data, np.uint8))
            assert (rmsg.encoding, rmsg.width, rmsg.height) == (msg.encoding, msg.width, msg.height)
        elif isinstance(msg, DisparityImage):
            assert rmsg.f == pytest.approx(msg.f) and rmsg.t == pytest.approx(msg.t)
            np.testing.assert_array_equal(rmsg.image.data, np.frombuffer(msg.image.data, np.uint8))
        elif isinstance(msg, PointCloud2):
            assert [f.name for f in rmsg.fields] == ["x", "y", "z", "rgb"]
            np.testing.assert_array_equal(rmsg.data, np.frombuffer(msg.data, np.uint8))
        elif isinstance(msg, CameraInfo):
            np.testing.assert_array_equal(rmsg.p, msg.p)


def test_file_layout_is_rosbag2_mcap(tmp_path):
    from mcap.reader import make_reader

    path, _ = _write(tmp_path / "layout.mcap", _messages(1))
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        meta = list(reader.iter_metadata())
    assert summary.statistics.message_count == 4 and summary.chunk_indexes
    assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}
    assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
    for c in summary.channels.values():
        assert "reliability: reliable" in c.metadata["offered_qos_profiles"]
    image_schema = next(s for s in summary.schemas.values() if s.name == "sensor_msgs/msg/Image")
    text = image_schema.data.decode()
    assert "MSG: std_msgs/Header" in text and "MSG: builtin_interfaces/Time" in text
    assert meta and meta[0].name == "rosbag2" and "message_count: 4" in meta[0].metadata["serialized_metadata"]


def test_truncated_bag_yields_complete_messages(tmp_path):
    msgs = [m for m in _messages(8) if m[0] == "/stereo/left/image_raw"]
    path, _ = _write(tmp_path / "full.mcap", msgs, chunk_size=20_000)  # several chunks
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    bag = BagReader(cut)
    assert bag.truncated and bag.problem
    got = list(bag.read())
    assert 0 < len(got) < len(msgs)
    for (_, msg, t), (rec, decoded) in zip(msgs, got):
        assert rec.log_time_ns == t and decoded == msg
    assert "TRUNCATED" in bag.summary_text()


def test_unclosed_bag_is_readable(tmp_path):
    path = tmp_path / "open.mcap"
    writer = BagWriter(path, chunk_size=1)  # every message closes a chunk
    msgs = _messages(2)
    for topic, msg, t in msgs:
        writer.write(topic, msg, t)
    writer._file.flush()  # as if the process died here
    bag = BagReader(path)
    assert bag.truncated and len(list(bag.messages())) == len(msgs)
    writer.close()
    assert not BagReader(path).truncated


def test_reader_rejects_non_bags(tmp_path):
    with pytest.raises(BagError, match="not found"):
        BagReader(tmp_path / "missing.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(BagError, match="not an MCAP"):
        BagReader(junk)


def test_topic_and_time_filters(tmp_path):
    msgs = _messages(4)
    bag = BagReader(_write(tmp_path / "f.mcap", msgs)[0])
    only = list(bag.messages(topics="/stereo/disparity"))
    assert [m.topic for m in only] == ["/stereo/disparity"] * 4
    later = list(bag.messages(start_ns=T0 + 33_000_000 * 2))
    assert len(later) == 8


def test_serialized_write_needs_type_for_new_topic(tmp_path):
    with BagWriter(tmp_path / "s.mcap") as bag:
        raw = serialize_message(convert.image_to_msg(np.zeros((2, 2), np.uint8)))
        with pytest.raises(BagError, match="msg_type"):
            bag.write("/x", raw, 1)
        bag.write("/x", raw, 1, msg_type="sensor_msgs/msg/Image")
    assert BagReader(tmp_path / "s.mcap").topics["/x"].message_count == 1


@pytest.mark.parametrize("name", ["sensor_msgs/msg/Image", "sensor_msgs/msg/PointCloud2",
                                  "stereo_msgs/msg/DisparityImage", "sensor_msgs/msg/CameraInfo"])
def test_generated_definitions_match_msg_files(name):
    """The fallback generator (no .msg files installed) describes the same wire format."""
    typesys = pytest.importorskip("rosbags.typesys")

    def parse(text):
        return typesys.get_types_from_msg(text, name)

    def fields(types, tname):
        return types[tname][1]

    full = msgdefs.message_definition(name)
    generated = msgdefs._generated_text(msgdefs.message_class(name))
    a = parse(full.split("=" * 80)[0])
    b = parse(generated)
    assert fields(a, name) == fields(b, name)


def test_type_names():
    assert msgdefs.type_name(Image) == "sensor_msgs/msg/Image"
    assert msgdefs.message_class("sensor_msgs/Image") is Image
    with pytest.raises(Exception, match="not installed"):
        msgdefs.message_class("nope_msgs/msg/Nothing")
