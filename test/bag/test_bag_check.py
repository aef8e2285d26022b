"""Damage reports of the reader, `canopy-stereo bag check|repair`, and `run` on bad bags."""
from __future__ import annotations

import os
import struct
from pathlib import Path

import pytest

pytest.importorskip("mcap")

from canopy_stereo.bag import BagError, BagReader, BagWriter, repair_bag  # noqa: E402
from canopy_stereo.bag.split import parse_size  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig  # noqa: E402


def _chunks(data: bytes) -> list[tuple[int, int]]:
    """(offset, end) of every chunk record, walking the framing up to the summary."""
    footer_at = len(data) - 8 - 29
    summary_start = struct.unpack_from("<Q", data, footer_at + 9)[0]
    out, p = [], 8
    while p < summary_start:
        op, length = struct.unpack_from("<BQ", data, p)
        if op == 0x06:
            out.append((p, p + 9 + length))
        p += 9 + length
    return out


@pytest.fixture
def damaged(tmp_path):
    """The croton bag with one byte flipped inside its second chunk's compressed data."""
    data = bytearray(Path(bundled_bag("croton")).read_bytes())
    a, b = _chunks(bytes(data))[1]
    data[(a + b) // 2] ^= 0x5A
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    return path, a


def test_damaged_chunk_is_reported_with_its_offset_and_skipped(damaged):
    path, offset = damaged
    original = {(m.topic, m.log_time_ns): m.data for m in BagReader(bundled_bag("croton")).messages()}
    seen = []
    bag = BagReader(path, on_damage=seen.append)
    got = list(bag.messages())
    assert 0 < len(got) < len(original)
    assert all(original[(m.topic, m.log_time_ns)] == m.data for m in got)
    assert len(seen) == 1 and seen[0].offset == offset and seen[0].messages_lost == len(original) - len(got)
    assert bag.messages_lost == len(original) - len(got)
    text = seen[0].describe(path)
    assert str(path) in text and f"offset {offset}" in text and "\n" not in text
    list(bag.messages())  # read again: the same damage is not reported twice
    assert len(seen) == 1
    with pytest.raises(BagError, match=f"offset {offset}"):
        list(BagReader(path, strict=True).messages())


def test_bag_check_reports_integrity_topics_counts_and_recoverable(cli, damaged, tmp_path):
    code, out, _ = cli("bag", "check", bundled_bag("croton"))
    assert code == 0 and "integrity: OK" in out and "/stereo/left/image_raw  4 msgs" in out
    path, offset = damaged
    code, out, _ = cli("bag", "check", path)
    assert code == 1
    assert "integrity: DAMAGED" in out and f"offset {offset}" in out and "messages lost" in out
    assert "messages readable intact: 10; lost: 2" in out
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(Path(bundled_bag("croton")).read_bytes()[:3_000_000])
    code, out, _ = cli("bag", "check", cut)
    assert code == 1 and "TRUNCATED" in out and "cut short" in out
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + os.urandom(5000))
    code, out, err = cli("bag", "check", junk)
    assert code == 1 and "DAMAGED" in out
    code, _, err = cli("bag", "check", tmp_path / "none.mcap")
    assert code == 2 and err.count("\n") == 1 and "not found" in err


def test_bag_repair_writes_a_complete_copy_of_everything_intact(cli, damaged, tmp_path):
    from mcap.reader import make_reader

    rosbags = pytest.importorskip("rosbags.highlevel")
    path, _ = damaged
    intact = [(m.topic, m.log_time_ns, m.data) for m in BagReader(path).messages()]
    out = tmp_path / "repaired.mcap"
    code, stdout, err = cli("bag", "repair", path, "-o", out)
    assert code == 0, err
    assert f"repaired: {out} ({len(intact)} messages, complete)" in stdout
    assert BagReader(out).verify().ok
    with open(out, "rb") as f:  # mcap's own reader, checking every CRC
        reader = make_reader(f, validate_crcs=True)
        got = [(c.topic, m.log_time, bytes(m.data)) for _, c, m in reader.iter_messages(log_time_order=True)]
    assert got == intact
    with rosbags.AnyReader([out]) as reader:
        assert [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()] == intact
    code, _, err = cli("bag", "repair", path, "-o", out)
    assert code == 2 and "exists" in err


def test_repair_of_an_unclosed_recording(tmp_path):
    """A recorder that never closed its file (killed): repair completes it."""
    from std_msgs.msg import String

    path = tmp_path / "open.mcap"
    w = BagWriter(path, chunk_size=1, flush_period_s=0)
    for k in range(5):
        w.write("/s", String(data=f"m{k}"), 1_000 + k)
    w._file.flush()  # the process dies here: no summary, no footer
    assert BagReader(path).truncated
    check = repair_bag(path, tmp_path / "fixed.mcap")
    assert not check.complete and sum(check.messages_recovered.values()) == 5
    fixed = BagReader(tmp_path / "fixed.mcap")
    assert fixed.verify().ok and [m.decode().data for m in fixed.messages()] == [f"m{k}" for k in range(5)]
    w.close()


def _statistics_at(data) -> int:
    footer_at = len(data) - 8 - 29
    p = struct.unpack_from("<Q", data, footer_at + 9)[0]
    while data[p] != 0x0B:  # the statistics record
        p += 9 + struct.unpack_from("<Q", data, p + 1)[0]
    return p


def test_summary_fields_are_checked_before_they_are_believed(tmp_path):
    """The issue's 1125899906842636 messages: a summary that does not add up is not believed
    even when its CRC matches (a lying writer); one without CRC is not used at all. The
    counts then come from the data."""
    data = bytearray(Path(bundled_bag("plants")).read_bytes())
    footer_at = len(data) - 8 - 29
    summary_start = struct.unpack_from("<Q", data, footer_at + 9)[0]
    struct.pack_into("<Q", data, _statistics_at(data) + 9, 1125899906842636)
    import zlib

    crc = zlib.crc32(bytes(data[footer_at:footer_at + 25]), zlib.crc32(bytes(data[summary_start:footer_at])))
    struct.pack_into("<I", data, footer_at + 25, crc)  # a CRC that matches the lie
    path = tmp_path / "lying.mcap"
    path.write_bytes(bytes(data))
    bag = BagReader(path)
    assert bag.message_count == 2 and any("not believed" in d.problem for d in bag.damage)
    assert len(list(bag.messages())) == 2
    struct.pack_into("<I", data, footer_at + 25, 0)  # no CRC: not used, not damage
    path.write_bytes(bytes(data))
    bag = BagReader(path)
    assert bag.message_count == 2 and not bag.damage
    check = bag.verify()
    assert check.ok and check.summary == "no CRC"


def test_parse_size():
    assert parse_size("500M") == 500 << 20 and parse_size("2G") == 2 << 30 and parse_size(1024) == 1024
    with pytest.raises(Exception, match="not a number of bytes"):
        parse_size("big")


@pytest.mark.slow
def test_cli_run_says_truncated_and_rejects_garbage_cdr(cli, tmp_path):
    pytest.importorskip("rclpy")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(Path(bundled_bag("croton")).read_bytes()[:200])
    code, _, err = cli("run", "--bag", cut, "--rig", bundled_rig("croton"))
    assert code == 2 and "truncated" in err and "topics: none" not in err and err.count("\n") == 1
    src = BagReader(bundled_bag("croton"))
    garbage = tmp_path / "garbage.mcap"
    with BagWriter(garbage) as w:
        for m in src.messages():
            data = os.urandom(len(m.data)) if m.topic.endswith("image_raw") else m.data
            w.write(m.topic, data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    code, out, err = cli("run", "--bag", garbage, "--rig", bundled_rig("croton"), "--rate", "0",
                         "--matcher", "sgbm", "--no-segment")
    assert code == 2, out + err
    assert "not valid sensor_msgs/msg/Image CDR" in err and "frames in: 0" not in out


@pytest.mark.slow
def test_bag_play_skips_a_damaged_chunk_with_a_warning(damaged):
    import subprocess
    import sys

    pytest.importorskip("rclpy")
    from canopy_stereo.ros.context import private_domain_id

    path, offset = damaged
    env = dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = "import sys; from canopy_stereo.ros.player import main; sys.exit(main())"
    res = subprocess.run([sys.executable, "-c", code, str(path), "--rate", "0", "--delay", "0"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert "published 10 messages" in res.stdout and "2 messages lost" in res.stdout
    assert f"offset {offset}" in res.stderr and "Traceback" not in res.stderr
    junk = path.with_name("junk.mcap")
    junk.write_bytes(b"\x89MCAP0\r\n")
    res = subprocess.run([sys.executable, "-c", code, str(junk), "--delay", "0"],
                         env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr


@pytest.mark.slow
def test_run_plays_the_intact_frames_of_a_damaged_bag(damaged):
    pytest.importorskip("rclpy")
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    path, offset = damaged
    result = run_bag(path, load_rig(bundled_rig("croton")), rate=0,
                     options=GraphOptions(matcher="sgbm", segment=False, parameter_services=False))
    assert result.frames_in == 3 and result.frames_out == 3  # one left image was in the damaged chunk
    text = "\n".join(result.summary_lines())
    assert f"input bag damaged: offset {offset}" in text and "messages lost" in text


def _bag_without_playable_frames(path: Path, *, damage: bool) -> Path:
    """Both input topics declared in the first chunk (beside one /other message); every
    left/right image in a later chunk of its own, each of those damaged when ``damage``
    (or no image at all when not)."""
    from std_msgs.msg import String

    src = BagReader(bundled_bag("croton"))
    images = [m for m in src.messages() if m.topic.endswith("image_raw")][:4]
    with BagWriter(path, chunk_size=64, flush_period_s=0) as w:
        for topic in ("/stereo/left/image_raw", "/stereo/right/image_raw"):
            w.add_topic(topic, "sensor_msgs/msg/Image")
        w.write("/other", String(data="first chunk"), images[0].log_time_ns)
        for m in images if damage else []:
            w.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    if damage:
        data = bytearray(path.read_bytes())
        for a, b in _chunks(bytes(data))[1:]:
            data[(a + b) // 2] ^= 0x5A
        path.write_bytes(bytes(data))
    return path


@pytest.mark.slow
def test_run_of_a_bag_that_plays_no_frame(tmp_path):
    """Regression (ruff F821): ``run_bag`` named an undefined ``damaged`` when no frame played,
    so such a bag raised NameError. A damaged one is a BagError naming the damage; an intact
    one without images plays nothing and says so."""
    pytest.importorskip("rclpy")
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    rig = load_rig(bundled_rig("croton"))
    options = GraphOptions(matcher="sgbm", segment=False, parameter_services=False)
    damaged = _bag_without_playable_frames(tmp_path / "damaged.mcap", damage=True)
    assert BagReader(damaged).verify().chunks_damaged == 4
    with pytest.raises(BagError, match="no frame could be played: the bag is damaged"):
        run_bag(damaged, rig, rate=0, options=options, idle_s=0.5)
    empty = _bag_without_playable_frames(tmp_path / "empty.mcap", damage=False)
    result = run_bag(empty, rig, rate=0, options=options, idle_s=0.5)
    assert result.frames_in == 0 and result.frames_out == 0 and not result.damage
