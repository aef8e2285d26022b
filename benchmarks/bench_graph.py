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

Multi-process mode (issue 12, ``--processes``; ``--processes-only`` skips the rest):
the four processing nodes (rectify, disparity with ELAS, segment, point_cloud), one
process each as ``ros2 run``/the launch file start them, are fed by a stand-in camera
driver (system-default QoS: reliable, keep last 10) publishing the same 640x480 frames
at each of ``--rates`` (default 15 and 30 Hz); printed: clouds per offered pair and
the median/90th-percentile latency (right image published -> ``points2`` received,
both clocks in the feeding process). Against it, the in-process graph
(``canopy-stereo run``) replays the same frames at the same rates (a bag stamped at
that rate, ``--rate 1``). Target: the multi-process graph loses no more than 20 %
against the in-process figures.

    .venv/bin/python benchmarks/bench_graph.py [--frames 40] [--matchers elas sgbm] [--executors per-node multi]
    .venv/bin/python benchmarks/bench_graph.py --processes-only --rates 15 30 --frames 60
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


def bench_processes(rate_hz: float, n_frames: int, log_dir: Path, matcher: str = "elas",
                    segment: bool = True, domain_id: int | None = None) -> dict:
    """Four node processes fed at ``rate_hz``: clouds per offered pair and latency (s)."""
    import time

    import numpy as np
    from sensor_msgs.msg import Image, PointCloud2

    from canopy_stereo.ros.context import private_domain_id

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's test package
    from test.support.ros_harness import PROCESSING_NODES, Probe, ProcessGroup, croton_frames, feed_pairs, wait_for

    domain = private_domain_id() if domain_id is None else domain_id
    group = ProcessGroup(domain, log_dir)
    nodes = PROCESSING_NODES if segment else tuple(n for n in PROCESSING_NODES if n != "segment_node")
    probe = None
    try:
        group.start_graph(bundled_rig("croton"), nodes=nodes, params={"disparity_node": {"matcher": matcher}})
        probe = Probe(domain)
        pub_l, pub_r = probe.publisher(Image, "left/image_raw"), probe.publisher(Image, "right/image_raw")
        clouds = probe.subscribe(PointCloud2, "points2")
        frames = croton_frames()
        if not wait_for(lambda: clouds.subscription.get_publisher_count() >= 1
                        and pub_l.get_subscription_count() >= 1 and pub_r.get_subscription_count() >= 1,
                        60.0, group=group):
            raise RuntimeError("the node processes did not connect:\n" + group.logs())
        stamp = 1_600_000_000_000_000_000
        while len(clouds) == 0:  # warm-up: first-call costs
            feed_pairs(pub_l, pub_r, frames, [stamp], 1.0)
            stamp += 10**8
            wait_for(lambda: len(clouds) > 0, 2.0, group=group)
        time.sleep(1.0)
        t0 = 1_700_000_000_000_000_000
        stamps = [t0 + int(k * 1e9 / rate_hz) for k in range(n_frames)]
        sent = feed_pairs(pub_l, pub_r, frames, stamps, rate_hz)
        wait_for(lambda: set(stamps) <= set(clouds.stamps()), 3.0)
        with clouds.lock:
            arrivals = {s: t for t, s, _ in clouds.items if s in sent}
        lat = np.array([arrivals[s] - sent[s] for s in arrivals])
        return {"clouds_per_pair": len(arrivals) / n_frames,
                "latency_median_s": float(np.median(lat)) if lat.size else float("nan"),
                "latency_p90_s": float(np.percentile(lat, 90)) if lat.size else float("nan")}
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()


def bench_in_process_at_rate(rig, rate_hz: float, n_frames: int, tmp: Path, matcher: str = "elas",
                             segment: bool = True) -> dict:
    """The in-process graph (``canopy-stereo run``) fed the same frames at ``rate_hz``."""
    bag = make_bag(tmp / f"rate{rate_hz:g}.mcap", n_frames, fps=rate_hz)
    options = GraphOptions(matcher=matcher, segment=segment, parameter_services=False)
    run_bag(make_bag(tmp / "warm_rate.mcap", 2), rig, rate=0, options=options)
    result = run_bag(bag, rig, rate=1.0, options=options)
    lat = result.latencies_s
    import numpy as np

    return {"clouds_per_pair": result.frames_out / max(1, result.frames_in),
            "latency_median_s": result.latency_median_s,
            "latency_p90_s": float(np.percentile(lat, 90)) if lat else float("nan")}


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
    p.add_argument("--processes", action="store_true",
                   help="also run the multi-process mode (4 node processes fed at --rates)")
    p.add_argument("--processes-only", action="store_true", help="only the multi-process mode")
    p.add_argument("--rates", nargs="*", type=float, default=[15.0, 30.0],
                   help="feeding rates of the multi-process mode (Hz)")
    args = p.parse_args(argv)
    rig = load_rig(bundled_rig("croton"))
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f}; "
          f"{args.frames} frames of {rig.image_size[0]}x{rig.image_size[1]} (paper rig)")
    with tempfile.TemporaryDirectory() as tmp:
        if args.processes or args.processes_only:
            print("multi-process (4 node processes, ELAS + GrabCut) vs in-process graph, fed at a fixed rate:")
            print(f"{'rate Hz':>8s} {'graph':14s} {'clouds/pair':>12s} {'latency median':>15s} {'p90':>8s}")
            for rate in args.rates:
                rows = [("processes", bench_processes(rate, args.frames, Path(tmp) / f"logs{rate:g}")),
                        ("in-process", bench_in_process_at_rate(rig, rate, args.frames, Path(tmp)))]
                for label, r in rows:
                    print(f"{rate:8.0f} {label:14s} {r['clouds_per_pair']:12.2f} "
                          f"{r['latency_median_s'] * 1e3:12.0f} ms {r['latency_p90_s'] * 1e3:5.0f} ms", flush=True)
            if args.processes_only:
                return 0
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
