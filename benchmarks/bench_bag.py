"""Benchmark: bag reading and recording (issue 13).

* Read throughput (MB of message data per second, and file MB/s) on the same bag of
  640x480 images (the bundled croton's, repeated), zstd and lz4: the validating
  :class:`~canopy_stereo.bag.BagReader` (every chunk CRC checked), mcap's reader
  without CRC checks (what BagReader used before: "unvalidated"), mcap's reader with
  ``validate_crcs=True``, and rosbags' ``AnyReader``. Best of ``--repeat`` runs.
* Recording overhead per message: :class:`~canopy_stereo.bag.BagWriter.write`
  (lock, counters, data CRC, periodic flush+fsync thread) against mcap's bare
  ``Writer.add_message``, for a CameraInfo-sized and a 921 600-byte image message.
* The fuzz counts of ``test/bag/test_bag_fuzz.py`` (224 damaged bags): foreign exceptions,
  altered messages returned, intact-chunk messages missing.

    .venv/bin/python benchmarks/bench_bag.py [--images 64] [--repeat 3] [--no-fuzz]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout first: canopy_stereo and its test package

from canopy_stereo.bag import BagReader, BagWriter  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag  # noqa: E402


def make_bag(path: Path, n_images: int, compression: str) -> tuple[Path, int]:
    """``n_images`` croton images (cycled) with increasing log times; returns (path, payload bytes)."""
    src = [m for m in BagReader(bundled_bag("croton")).messages() if m.topic.endswith("image_raw")]
    payload = 0
    with BagWriter(path, compression=compression, flush_period_s=0) as w:
        for k in range(n_images):
            m = src[k % len(src)]
            w.write(m.topic, m.data, 1_000_000_000 + k * 33_000_000, publish_time_ns=None, msg_type=m.type_name)
            payload += len(m.data)
    return path, payload


def read_ours(path):
    n = 0
    for m in BagReader(path).messages():
        n += len(m.data)
    return n


def read_mcap(path, validate):
    from mcap.reader import make_reader

    n = 0
    with open(path, "rb") as f:
        for _, _, m in make_reader(f, validate_crcs=validate).iter_messages(log_time_order=True):
            n += len(m.data)
    return n


def read_rosbags(path):
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([Path(path)]) as reader:
        for _, _, raw in reader.messages():
            n += len(raw)
    return n


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def bench_read(tmp: Path, n_images: int, repeat: int) -> None:
    print(f"read throughput, {n_images} images of 640x480 bgr8 (best of {repeat}):")
    print(f"  {'compression':<11} {'reader':<34} {'data MB/s':>10} {'file MB/s':>10}")
    for comp in ("zstd", "lz4"):
        path, payload = make_bag(tmp / f"bench_{comp}.mcap", n_images, comp)
        size = path.stat().st_size
        readers = [("BagReader (validating)", lambda path=path: read_ours(path)),
                   ("mcap, no CRC checks (unvalidated)", lambda path=path: read_mcap(path, False)),
                   ("mcap, validate_crcs=True", lambda path=path: read_mcap(path, True))]
        try:
            import rosbags  # noqa: F401

            readers.append(("rosbags AnyReader", lambda path=path: read_rosbags(path)))
        except ImportError:
            pass
        for name, fn in readers:
            assert fn() == payload, name
            t = best_time(fn, repeat)
            print(f"  {comp:<11} {name:<34} {payload / t / 1e6:>10.0f} {size / t / 1e6:>10.0f}")


def bench_record(tmp: Path, repeat: int) -> None:
    """Per-message cost of BagWriter.write from a recorder thread (how bag_record's and run's
    ROS callbacks call it), from the main thread (handed to the writer's thread so that
    Ctrl-C cannot cut a write in half), and of mcap's bare Writer.add_message."""
    import threading

    from mcap.writer import CompressionType, Writer
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import CameraInfo

    small = serialize_message(CameraInfo())
    big = next(m.data for m in BagReader(bundled_bag("croton")).messages("/stereo/left/image_raw"))
    print(f"recording cost per message (us; lz4; best of {repeat}):")
    print(f"  {'message':<22} {'BagWriter, thread':>18} {'BagWriter, main':>16} {'mcap bare':>10} "
          f"{'overhead (thread)':>18}")
    for label, data, n in ((f"CameraInfo {len(small)} B", small, 20000), (f"Image {len(big)} B", big, 300)):
        def ours(data=data, n=n):
            with BagWriter(tmp / "rec.mcap", compression="lz4") as w:
                for k in range(n):
                    w.write("/t", data, k, publish_time_ns=k, msg_type="sensor_msgs/msg/CameraInfo")

        def ours_thread():
            t = threading.Thread(target=ours)
            t.start()
            t.join()

        def bare(data=data, n=n):
            with open(tmp / "bare.mcap", "wb") as f:
                w = Writer(f, compression=CompressionType.LZ4)
                w.start(profile="ros2")
                sid = w.register_schema("sensor_msgs/msg/CameraInfo", "ros2msg", b"")
                cid = w.register_channel("/t", "cdr", sid)
                for k in range(n):
                    w.add_message(cid, log_time=k, data=data, publish_time=k, sequence=k)
                w.finish()

        t_thread = best_time(ours_thread, repeat) / n * 1e6
        t_main = best_time(ours, repeat) / n * 1e6
        t_bare = best_time(bare, repeat) / n * 1e6
        print(f"  {label:<22} {t_thread:>18.1f} {t_main:>16.1f} {t_bare:>10.1f} {t_thread - t_bare:>+18.1f}")


def bench_fuzz(tmp: Path) -> None:
    from test.bag.test_bag_fuzz import COUNTS, build_sources, run_fuzz

    t = time.perf_counter()
    tally, failures = run_fuzz(build_sources(tmp), COUNTS, tmp)
    kinds = ", ".join(f"{k[9:]} {v}" for k, v in sorted(tally.items())
                      if k.startswith("variants_") and k != "variants_losing_messages")
    print(f"fuzz ({time.perf_counter() - t:.1f} s): {tally['variants']} damaged bags ({kinds})")
    print(f"  foreign exceptions: {tally['foreign_exceptions']}, altered messages returned: "
          f"{tally['altered_messages_returned']}, BagError at open: {tally['bag_error_at_open']}")
    print(f"  intact-chunk messages: {tally['intact_chunk_messages']}, of them missing: "
          f"{tally['intact_chunk_messages_missing']}; bags that lost messages: "
          f"{tally['variants_losing_messages']} (all reported); messages returned "
          f"{tally['messages_returned']}, lost {tally['messages_lost']}; strict-mode BagErrors "
          f"{tally['strict_bag_errors']}")
    if failures:
        print("  VIOLATIONS:\n    " + "\n    ".join(failures[:20]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--images", type=int, default=64, help="images in the read benchmark bag")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-fuzz", action="store_true", help="skip the fuzz counts")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        bench_read(tmp, args.images, args.repeat)
        bench_record(tmp, args.repeat)
        if not args.no_fuzz:
            bench_fuzz(tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main())
