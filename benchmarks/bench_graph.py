"""Benchmark: the ROS 2 node graph replaying 640x480 paper-rig frames (issue 5).

Target: ``canopy-stereo run --rate 0`` at >= 10 frames/s, and < 150 ms from a
raw pair to its ``points2``, on the 2-core development machine.

A bag of ``--frames`` 640x480 frames is made from the bundled synthetic croton
(paper rig, 15 frames/s stamps) and replayed through the real nodes, built
in-process on a private DDS domain, exactly as ``canopy-stereo run`` does:

* throughput: ``--rate 0`` with two frames in flight (the run default);
* latency: ``--rate 0`` with one frame in flight (an unloaded pipeline:
  raw pair published -> ``points2`` received);

for each matcher and with/without ``segment_node``. Also prints the busy time
per frame of every node (seconds inside its callbacks), and the figures of the
CLI itself for the default configuration (ELAS, segmentation, recording).

``--executors per-node multi`` also runs the graph on one rclpy
MultiThreadedExecutor for comparison.

    .venv/bin/python benchmarks/bench_graph.py [--frames 40] [--matchers elas sgbm] [--executors per-node multi]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canopy_stereo.cli import main as cli_main  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.bag import BagReader  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig, write_stereo_bag  # noqa: E402
from canopy_stereo.ros.convert import msg_to_image  # noqa: E402
from canopy_stereo.ros.graph import GraphOptions  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402


def make_bag(path: Path, n_frames: int, fps: float = 15.0) -> Path:
    """``n_frames`` croton frames (the bundled ones, cycled) with fresh stamps."""
    bag = BagReader(bundled_bag("croton"))
    lefts = [msg_to_image(m).copy() for _, m in bag.read("/stereo/left/image_raw")]
    rights = [msg_to_image(m).copy() for _, m in bag.read("/stereo/right/image_raw")]
    t0, period = 1_704_067_200_000_000_000, int(1e9 / fps)
    frames = [(lefts[k % len(lefts)], rights[k % len(rights)], t0 + k * period, t0 + k * period + 4_000_000)
              for k in range(n_frames)]
    return write_stereo_bag(path, frames, compression="lz4")


def per_frame_busy(result) -> str:
    n = max(1, result.frames_in)
    return ", ".join(f"{name.replace('_node', '')} {st['busy_s'] / n * 1e3:.0f}"
                     for name, st in sorted(result.graph_stats.items()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--matchers", nargs="*", default=["elas", "sgbm"])
    p.add_argument("--executors", nargs="*", default=["per-node"], choices=["per-node", "multi"])
    p.add_argument("--no-cli", action="store_true", help="skip the CLI run")
    args = p.parse_args(argv)
    rig = load_rig(bundled_rig("croton"))
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f}; "
          f"{args.frames} frames of {rig.image_size[0]}x{rig.image_size[1]} (paper rig)")
    with tempfile.TemporaryDirectory() as tmp:
        bag = make_bag(Path(tmp) / "bench.mcap", args.frames)
        warm = make_bag(Path(tmp) / "warm.mcap", 2)
        print(f"{'executor':9s} {'matcher':8s} {'segment':8s} {'frames/s':>9s} {'latency median':>15s} "
              f"{'latency max':>12s}  busy ms/frame per node")
        for executor, matcher, segment in [(e, m, s) for e in args.executors for m in args.matchers
                                           for s in (True, False)]:
            options = GraphOptions(matcher=matcher, segment=segment, parameter_services=False,
                                   executor=executor)
            run_bag(warm, rig, rate=0, options=options)  # JIT caches, first-call costs
            thr = run_bag(bag, rig, rate=0, options=options, max_in_flight=2)
            lat = run_bag(bag, rig, rate=0, options=options, max_in_flight=1)
            print(f"{executor:9s} {matcher:8s} {str(segment):8s} {thr.fps:9.2f} "
                  f"{lat.latency_median_s * 1e3:12.0f} ms {max(lat.latencies_s) * 1e3:9.0f} ms  "
                  f"{per_frame_busy(thr)}", flush=True)
        if not args.no_cli:
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                cli_main(["run", "--bag", str(bag), "--rig", str(bundled_rig("croton")), "--rate", "0",
                          "--record", str(Path(tmp) / "out.mcap")])
            print("canopy-stereo run --rate 0 --record OUT.mcap (defaults: ELAS, segmentation):")
            for line in out.getvalue().splitlines():
                if not line.startswith("recorded"):
                    print("  " + line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
