"""``canopy-stereo batch`` benchmark: bags per minute on Dask, its overhead, scheduler memory.

1. Throughput: ``--bags`` bags of the synthetic croton (``--size`` pixels wide, 4:3,
   ``--frames`` stereo pairs each, with metadata and rig records) measured by
   :func:`canopy_stereo.batch.run_batch` on an embedded LocalCluster of 1 and of 2
   worker processes (wall time of the whole call: cluster start, workers' imports,
   the bags, the tables), and by a plain serial loop over the same bags
   (``run_bag_task`` in a fresh Python process, imports included). Prints bags/min,
   the 2-worker scaling efficiency (rate2 / (2 rate1)) and Dask's overhead against
   the serial loop ((t_1worker - t_serial) / t_serial).
2. Scheduler memory: ``--queued`` tiny bags (one 64x48 pair, a copy per bag) submitted
   to a ``dask scheduler`` process that has no worker yet, so every task waits in its
   queue; the scheduler's resident memory before and with the tasks queued (and the
   client's). With ``--drain`` two ``dask worker`` processes then run them all
   (tiny-bag throughput: the per-task cost of the engine).

Usage:
    python benchmarks/bench_batch.py [--bags 8] [--size 320] [--frames 2] [--queued 1000] [--drain]
                                     [--workers 1,2] [--keep DIR]

Figures depend on the machine and its load (2 shared cores here): re-measure on an idle machine.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from canopy_stereo.batch import BatchOptions, run_batch  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402

EPOCH_NS = 1_777_593_600_000_000_000


def scaled_rig(width: int):
    paper = load_rig(REPO / "config" / "paper_rig.yaml")
    s = width / 640.0
    S = np.diag([s, s, 1.0])
    return type(paper)(P_left=S @ paper.P_left, P_right=S @ paper.P_right,
                       image_size=(width, round(480 * s)), world_unit="mm")


def make_bags(folder: Path, n: int, width: int, frames: int) -> list[Path]:
    """``n`` croton bags (seeds 0..n-1) with metadata and rig records."""
    from canopy_stereo.ros.bundled import croton_frames, write_stereo_bag

    folder.mkdir(parents=True, exist_ok=True)
    rig = scaled_rig(width)
    out = []
    for i in range(n):
        path = folder / f"plant{i % 4}_week{i // 4}.mcap"
        if not path.is_file():
            pairs, _, (dmin, dmax) = croton_frames(rig, frames, seed=i)
            write_stereo_bag(path, pairs, rig=rig.with_extra(disp_min=dmin, disp_max=dmax), metadata={
                "plant_id": f"P{i % 4}", "plot": f"row{i % 2}", "date": f"2026-05-{1 + 7 * (i // 4):02d}"})
        out.append(path)
    return out


def _cpu_s() -> float:
    """CPU seconds (user + system) of this process and its reaped children so far."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def serial_loop(paths) -> float:
    """Seconds of a plain loop over ``paths`` in a fresh Python (imports included)."""
    code = ("import sys, time; t = time.perf_counter()\n"
            "from canopy_stereo.batch.work import BatchOptions, run_bag_task\n"
            "res = [run_bag_task(p, BatchOptions()) for p in sys.argv[1:]]\n"
            "assert all(s == 'ok' for s, _ in res), [r for r in res if r[0] != 'ok']\n"
            "print(time.perf_counter() - t)")
    env = {**os.environ, "NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", code, *map(str, paths)], capture_output=True, text=True,
                         env=env, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def dask_run(paths, workers: int, out: Path) -> float:
    shutil.rmtree(out, ignore_errors=True)
    t = time.perf_counter()
    summary = run_batch(paths, out, options=BatchOptions(), workers=workers, progress=False, plots=False)
    dt = time.perf_counter() - t
    assert summary.succeeded == len(paths), summary.lines()
    return dt


def timed(fn, *args) -> tuple[float, float]:
    """``(wall s, CPU s)`` of ``fn(*args)`` (CPU: this process and the children it reaped:
    the serial loop's Python, the LocalCluster's worker processes)."""
    time.sleep(0.5)  # let the previous run's processes be reaped
    c = _cpu_s()
    wall = fn(*args)
    time.sleep(0.5)
    return wall, _cpu_s() - c


def _rss_mb(pid: int) -> float:
    import psutil

    return psutil.Process(pid).memory_info().rss / 1e6


def queued_memory(folder: Path, n: int, drain: bool) -> dict:
    """Scheduler RSS with ``n`` tiny-bag tasks queued (no worker), optionally drained."""
    from distributed import Client

    from canopy_stereo.batch.work import run_bag_task

    one = make_bags(folder / "one", 1, 64, 1)[0]
    tiny = folder / "tiny"
    tiny.mkdir(exist_ok=True)
    paths = []
    for i in range(n):
        p = tiny / f"tiny{i:05d}.mcap"
        if not p.exists():
            os.link(one, p) if hasattr(os, "link") else shutil.copy(one, p)
        paths.append(str(p))
    sched_file = folder / "scheduler.json"
    sched_file.unlink(missing_ok=True)
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    sched = subprocess.Popen(dask + ["--scheduler-file", str(sched_file), "--port", "0", "--host", "127.0.0.1",
                                     "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = []
    try:
        while not sched_file.is_file():
            time.sleep(0.1)
        address = json.loads(sched_file.read_text())["address"]
        client = Client(address, timeout="30s")
        time.sleep(1.0)
        base_s, base_c = _rss_mb(sched.pid), _rss_mb(os.getpid())
        opts = BatchOptions()
        t = time.perf_counter()
        futures = [client.submit(run_bag_task, p, opts, key=f"canopy-bag-{i}-{Path(p).name}", pure=False)
                   for i, p in enumerate(paths)]
        while client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) < n:
            time.sleep(0.1)
        submit_s = time.perf_counter() - t
        time.sleep(1.0)
        res = {"queued": n, "submit_s": submit_s, "scheduler_rss_before_mb": base_s,
               "scheduler_rss_queued_mb": _rss_mb(sched.pid), "client_rss_before_mb": base_c,
               "client_rss_queued_mb": _rss_mb(os.getpid())}
        if drain:
            for _ in range(2):
                workers.append(subprocess.Popen(
                    [sys.executable, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(sched_file),
                     "--nthreads", "1", "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
            client.wait_for_workers(2, timeout=120)
            t = time.perf_counter()
            statuses = [f.result()[0] for f in futures]
            res["drain_s"] = time.perf_counter() - t
            res["drain_ok"] = statuses.count("ok")
            res["scheduler_rss_after_mb"] = _rss_mb(sched.pid)
        client.close()
        return res
    finally:
        for p in workers + [sched]:
            p.terminate()
        for p in workers + [sched]:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bags", type=int, default=8)
    p.add_argument("--size", type=int, default=320, help="image width (px), 4:3")
    p.add_argument("--frames", type=int, default=2)
    p.add_argument("--workers", default="1,2", help="LocalCluster sizes to run")
    p.add_argument("--queued", type=int, default=1000, help="tiny bags queued for the memory figure (0 = skip)")
    p.add_argument("--drain", action="store_true", help="then run the queued tiny bags on 2 dask workers")
    p.add_argument("--keep", type=Path, help="folder for the bags (kept; reused next time)")
    a = p.parse_args()
    folder = a.keep or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f} (figures are noisy "
              "when the machine is shared)")
        if a.bags:
            paths = make_bags(folder / f"bags_{a.size}_{a.frames}", a.bags, a.size, a.frames)
            n = len(paths)
            print(f"{n} bags of {a.frames} stereo pairs at {a.size}x{round(a.size * 0.75)}")
            t_serial, c_serial = timed(serial_loop, paths)
            rows = [("serial loop (fresh process)", t_serial, c_serial)]
            times, cpus = {}, {}
            for w in (int(v) for v in a.workers.split(",")):
                times[w], cpus[w] = timed(dask_run, paths, w, folder / f"out_{w}")
                rows.append((f"dask LocalCluster, {w} worker(s)", times[w], cpus[w]))
            print(f"{'run':34s} {'wall s':>7s} {'bags/min':>9s} {'CPU s':>7s} {'CPU s/bag':>10s}")
            for name, t, c in rows:
                print(f"{name:34s} {t:7.1f} {n / (t / 60):9.1f} {c:7.1f} {c / n:10.2f}")
            if 1 in times:
                wall = 100 * (times[1] - t_serial) / t_serial
                print(f"overhead of dask (1 worker) vs the serial loop: wall {wall:+.0f} %, "
                      f"CPU {100 * (cpus[1] - c_serial) / c_serial:+.0f} % (CPU is the figure a shared machine keeps)")
            if 1 in times and 2 in times:
                print(f"scaling efficiency 1 -> 2 workers: {100 * times[1] / (2 * times[2]):.0f} % (wall; needs "
                      "two idle cores)")
        if a.queued:
            r = queued_memory(folder, a.queued, a.drain)
            print(f"{r['queued']} tiny bags queued in {r['submit_s']:.1f} s: scheduler RSS "
                  f"{r['scheduler_rss_before_mb']:.0f} -> {r['scheduler_rss_queued_mb']:.0f} MB "
                  f"({1000 * (r['scheduler_rss_queued_mb'] - r['scheduler_rss_before_mb']) / r['queued']:.1f} kB/bag); "
                  f"client {r['client_rss_before_mb']:.0f} -> {r['client_rss_queued_mb']:.0f} MB")
            if "drain_s" in r:
                print(f"drained on 2 dask workers in {r['drain_s']:.1f} s ({r['queued'] / r['drain_s']:.1f} tiny "
                      f"bags/s, {r['drain_ok']} ok); scheduler RSS after {r['scheduler_rss_after_mb']:.0f} MB")
    finally:
        if a.keep is None:
            shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
