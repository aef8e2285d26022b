"""Benchmark: ray-cast rendering of the simulator's scenes through the paper's rig.

Target (issue 4): a 640x480 stereo pair in under 1 s. Prints, per scene, the
wall-clock and CPU time of a whole pair (both views with 4 anti-aliasing
samples per pixel plus the centre ray, sensor model and ground truth), the
share of each stage, and the numba compile/cache-load time of the first call.

    .venv/bin/python benchmarks/bench_render.py [--repeat 7] [--supersample 2]
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canopy_stereo.sim import SCENES, render_pair, resolve_rig, scene_for_rig  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=7, help="timed runs per scene")
    parser.add_argument("--supersample", type=int, default=2, help="anti-aliasing level")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), help="scenes to time")
    args = parser.parse_args(argv)

    rig = resolve_rig(None)
    w, h = rig.image_size
    print(f"rig: config/paper_rig.yaml, {w}x{h}, supersample {args.supersample}, "
          f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    t0 = time.perf_counter()
    render_pair(scene_for_rig("croton", rig), rig, supersample=args.supersample)
    print(f"first call (numba compile or cache load + render): {time.perf_counter() - t0:.2f} s")
    print(f"{'scene':<15}{'primitives':>11}{'leaves':>8}{'build s':>9}{'pair wall s':>13}"
          f"{'pair cpu s':>12}{'left':>7}{'right':>7}{'sensor+truth':>14}")
    worst = 0.0
    for name in args.scenes:
        t0 = time.perf_counter()
        scene = scene_for_rig(name, rig)
        build = time.perf_counter() - t0
        render_pair(scene, rig, supersample=args.supersample)  # warm the caches of this scene
        walls, cpus, stages = [], [], []
        for _ in range(args.repeat):
            c0, t0 = time.process_time(), time.perf_counter()
            sim = render_pair(scene, rig, supersample=args.supersample)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
            stages.append(sim.timings)
        wall, cpu = statistics.median(walls), statistics.median(cpus)
        share = {k: statistics.median(s[k] for s in stages) for k in ("left", "right", "sensor")}
        worst = max(worst, wall)
        print(f"{name:<15}{len(scene.primitives):>11}{len(scene.leaves):>8}{build:>9.3f}"
              f"{wall:>13.3f}{cpu:>12.3f}{share['left']:>7.3f}{share['right']:>7.3f}"
              f"{share['sensor']:>14.3f}")
    verdict = "meets" if worst < 1.0 else "misses"
    print(f"slowest pair (median wall time): {worst:.3f} s -> {verdict} the 1 s target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
