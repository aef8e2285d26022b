"""Benchmark: the node processes' glibc malloc settings -- speed kept, retention lost (issue 13).

Replays a bag of ``--frames`` croton frames (paper rig, 640x480) through the real
graph as ``canopy-stereo run --rate 0 --record`` does (ELAS, GrabCut segmentation,
recording), once per allocator setting, each in a fresh process:

* ``glibc``: no tuning (128 kB adaptive mmap threshold), rmw_fastrtps's reader memory;
* ``previous``: 256 MiB mmap threshold, 1 GiB trim threshold, 256 MiB top pad (kept up
  to 1 GiB after one oversize message), rmw_fastrtps's reader memory;
* ``current``: :data:`canopy_stereo.ros.context.PIPELINE_MALLOC_OPTIONS` and
  :func:`~canopy_stereo.ros.context.use_bounded_dds_memory`;
* ``MMAP:TRIM:PAD`` (MiB): other settings to compare;

and prints system and user CPU time per frame (all threads), frames per second, the
peak RSS and the RSS at the end. Target: ``current`` as fast as ``previous`` (system
time per frame within noise), far below ``glibc``.

    .venv/bin/python benchmarks/bench_allocator.py [--frames 30] [--variants glibc previous current]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

#: name -> (malloc settings: None = glibc's, "default" = the package's, or mallopt values; bounded DDS memory)
VARIANTS = {
    "glibc": (None, False),
    "previous": ({"mmap_threshold": 256 << 20, "trim_threshold": 1 << 30, "top_pad": 256 << 20}, False),
    "current": ("default", True),
}


def variant_setting(name: str):
    """A named variant, or ``MMAP:TRIM:PAD`` in MiB (with bounded DDS memory); a suffix
    ``+arenaN`` also sets glibc's ``M_ARENA_MAX``."""
    name = name.split("+")[0]
    if name in VARIANTS:
        return VARIANTS[name]
    mmap, trim, pad = (int(v) << 20 for v in name.split(":"))
    return {"mmap_threshold": mmap, "trim_threshold": trim, "top_pad": pad}, True


def child(variant: str, bag: str, warm: str, out_dir: str) -> dict:
    """Run the graph over ``warm`` then ``bag`` with one allocator setting; figures of the second run."""
    import resource
    import time

    from canopy_stereo.ros import context

    setting, bounded_dds = variant_setting(variant)
    if "+arena" in variant:
        import ctypes

        assert ctypes.CDLL(None).mallopt(-8, int(variant.split("+arena")[1])) == 1  # M_ARENA_MAX
    if not bounded_dds:
        context.use_bounded_dds_memory = lambda: False  # rmw_fastrtps's reader memory
    if setting is None:
        context.tune_memory_allocator = lambda *a, **k: False  # the glibc defaults
    elif setting == "default":
        assert context.tune_memory_allocator()
    else:
        assert context.tune_memory_allocator(**setting)
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_rig
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    rig = load_rig(bundled_rig("croton"))
    options = GraphOptions(matcher="elas", segment=True, parameter_services=False)
    run_bag(Path(warm), rig, rate=0, options=options, record=Path(out_dir) / f"rec_{variant}_warm.mcap")
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    res = run_bag(Path(bag), rig, rate=0, options=options, record=Path(out_dir) / f"rec_{variant}.mcap")
    r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    n = max(1, res.frames_out)
    with open("/proc/self/status") as fh:
        rss = next(int(line.split()[1]) * 1024 for line in fh if line.startswith("VmRSS:"))
    return {"variant": variant, "frames": res.frames_out, "fps": res.fps,
            "sys_ms": (r1.ru_stime - r0.ru_stime) / n * 1e3, "user_ms": (r1.ru_utime - r0.ru_utime) / n * 1e3,
            "wall_s": t1 - t0, "peak_rss_mib": r1.ru_maxrss / 1024, "rss_mib": rss / 2**20}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--variants", nargs="*", default=list(VARIANTS),
                   help=f"{', '.join(VARIANTS)} or MMAP:TRIM:PAD in MiB (default: the named ones)")
    p.add_argument("--repeat", type=int, default=1, help="runs per variant (interleaved)")
    p.add_argument("--child", nargs=4, metavar=("VARIANT", "BAG", "WARM", "OUT"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print(json.dumps(child(*args.child)))
        return 0
    from bench_graph import make_bag

    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f}; {args.frames} croton "
          "frames, ELAS + GrabCut + recording, --rate 0")
    print(f"{'allocator':10s} {'sys ms/frame':>13s} {'user ms/frame':>14s} {'frames/s':>9s} "
          f"{'peak RSS':>9s} {'end RSS':>8s}")
    with tempfile.TemporaryDirectory() as tmp:
        bag = make_bag(Path(tmp) / "bench.mcap", args.frames)
        warm = make_bag(Path(tmp) / "warm.mcap", 3)
        for _ in range(args.repeat):
            for variant in args.variants:
                out = subprocess.run([sys.executable, __file__, "--child", variant, str(bag), str(warm), tmp],
                                     env=env, capture_output=True, text=True, timeout=1800)
                if out.returncode != 0:
                    print(f"{variant}: failed: {out.stderr[-500:]}")
                    continue
                r = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"{variant:10s} {r['sys_ms']:13.1f} {r['user_ms']:14.1f} {r['fps']:9.2f} "
                      f"{r['peak_rss_mib']:6.0f} MiB {r['rss_mib']:5.0f} MiB", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
