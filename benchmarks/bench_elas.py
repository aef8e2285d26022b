"""ELAS benchmark: accuracy and speed on every ground-truth pair in ../shared/data.

Methods: this package's ELAS (robotics and middlebury presets, each with and without
``subpixel``; robotics also with the linear adaptive-mean weights, accuracy only),
OpenCV StereoSGBM (block 5, P1 600, P2 2400, as in elas.md) and, when
a Python with ``pyelas`` is available, the original libelas (run in that Python in a
subprocess, never imported here). Prints one table: size, median ms of 5 calls after
a warm-up, density, bad>0.5, bad>1, bad>2, EPE; then the libelas targets, the
sub-pixel answer and the first-call time of a fresh process.

Usage:
    python benchmarks/bench_elas.py [--data ../shared/data] [--pairs tsukuba,teddy]
                                    [--reps 5] [--pyelas /path/to/python] [--no-fresh]
    python benchmarks/bench_elas.py --stages [--left L.png --right R.png | --pairs tsukuba]
                                    [--preset robotics] [--disp-min 84 --disp-max 167]
                                    [--scale 2] [--threads 1,2] [--right-map] [--reps 20]
                                    [--subsampling]

    python benchmarks/bench_elas.py --target [--reps 5] [--pyelas /path/to/python]

``--target`` prints issue 28's ELAS figures: per MiddEval3 training scene (quarter size) and
preset, CPU ms of one-thread ELAS against libelas's (``time.process_time``, the same load),
the ratio and bad>2 / density against libelas's; then 1280x720 CPU and wall ms per frame
on one and two threads.

``--stages`` times ELAS alone, stage by stage, on one pair (``--left``/``--right``
images, any size and colour, or the first of ``--pairs``; ``--scale`` resizes it):
per stage the median wall ms of ``--reps`` calls after a warm-up, then the median
wall and CPU ms (``time.process_time``, all threads) of a whole call, for each
numba thread count of ``--threads``.

libelas: ``--pyelas`` or ``$PYELAS_PYTHON`` names a Python interpreter that can
``import elas`` (see elas.md); by default ``/work/pyelas-venv/bin/python`` and
``~/pyelas-venv/bin/python`` are tried. ELAS and libelas search disparities 0..255
(their default); SGBM searches 0..ceil(max GT / 16) * 16.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from canopy_stereo.disparity.metrics import evaluate_disparity  # noqa: E402
from canopy_stereo.io.images import read_image, to_gray  # noqa: E402
from canopy_stereo.io.middlebury import read_disparity  # noqa: E402

ELAS_CONFIGS = [("robotics", False), ("robotics", True), ("middlebury", False),
                ("middlebury", True)]


def find_pairs(data: Path) -> list[dict]:
    """Every pair with ground truth: name, left/right/gt paths, PNG scale."""
    pairs = []

    def add(name, folder, left, right, gt, scale):
        folder = data / folder
        if (folder / left).is_file() and (folder / gt).is_file():
            pairs.append({"name": name, "left": folder / left, "right": folder / right,
                          "gt": folder / gt, "scale": scale})

    add("Tsukuba", "middlebury2001/Tsukuba", "imL.png", "imR.png", "truedisp.pgm", 16)
    add("Venus", "middlebury2001/Venus", "imL.png", "imR.png", "disp2.pgm", 8)
    add("Teddy03", "middlebury2003_quartersize/Teddy", "imL.png", "imR.png", "disp2.png", 4)
    add("Cones03", "middlebury2003_quartersize/Cones", "imL.png", "imR.png", "disp2.png", 4)
    for scene in ("Aloe", "Flowerpots"):
        add(f"{scene}06", f"middlebury2006_thirdsize/{scene}", "view1.png", "view5.png",
            "disp1.png", 3)
    q = data / "middlebury_MiddEval3_trainingQ"
    if q.is_dir():
        for scene in sorted(p.name for p in q.iterdir() if p.is_dir()):
            add(f"{scene}Q", f"middlebury_MiddEval3_trainingQ/{scene}", "im0.png", "im1.png",
                "disp0GT.pfm", None)
    add("AloeFull", "opencv_aloe_fullsize", "aloeL.jpg", "aloeR.jpg", "aloeGT.png", 1)
    return pairs


def selected_pairs(data: Path, names: str) -> list[dict]:
    """The ground-truth pairs under ``data`` named in the comma-separated ``names`` (all if empty)."""
    pairs = find_pairs(data)
    if names:
        wanted = {p.lower() for p in names.split(",")}
        pairs = [p for p in pairs if p["name"].lower() in wanted]
    return pairs


def load_pair(pair: dict):
    left = to_gray(read_image(pair["left"]))
    right = to_gray(read_image(pair["right"]))
    gt = read_disparity(pair["gt"], pair["scale"])
    return left, right, gt


def timed(fn, reps: int):
    """(result of the warm-up call, median seconds of ``reps`` further calls)."""
    out = fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return out, float(np.median(times))


def sgbm(left, right, disp_max):
    num = int(np.ceil((disp_max + 1) / 16.0)) * 16
    m = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num, blockSize=5, P1=600, P2=2400,
                              disp12MaxDiff=1, uniquenessRatio=10, speckleWindowSize=100,
                              speckleRange=2)
    raw = m.compute(left, right)
    d = raw.astype(np.float32) / 16.0
    d[raw < 0] = -1.0
    return d


# --------------------------------------------------------------------- libelas
LIBELAS_RUNNER = r'''
import json, sys, time
import numpy as np
import elas
job = json.load(open(sys.argv[1]))
out = {}
for item in job["pairs"]:
    data = np.load(item["npz"])
    left, right = data["left"], data["right"]
    for preset in ("robotics", "middlebury"):
        e = elas.Elas()
        e.set_preset(getattr(elas, "PRESET_" + preset.upper()))
        dl, _ = e.process(left, right)
        times, cpu = [], []
        for _ in range(job["reps"]):
            c, t = time.process_time(), time.perf_counter()
            e.process(left, right)
            times.append(time.perf_counter() - t); cpu.append(time.process_time() - c)
        path = item["npz"].replace(".npz", "_" + preset + ".npy")
        np.save(path, np.asarray(dl, np.float32))
        out[item["name"] + "/" + preset] = {"disp": path, "ms": 1000 * float(np.median(times)),
                                            "cpu_ms": 1000 * float(np.median(cpu))}
json.dump(out, open(sys.argv[2], "w"))
'''


def find_pyelas(explicit: str | None) -> str | None:
    candidates = [explicit, os.environ.get("PYELAS_PYTHON"), "/work/pyelas-venv/bin/python",
                  str(Path.home() / "pyelas-venv" / "bin" / "python")]
    for c in candidates:
        if not c or not Path(c).is_file():
            continue
        ok = subprocess.run([c, "-c", "import elas"], capture_output=True).returncode == 0
        if ok:
            return c
    return None


def run_libelas(python: str, loaded: dict, reps: int, workdir: Path, *, cpu: bool = False) -> dict:
    """libelas's left maps and median ms (wall; CPU with ``cpu``) per ``pair/preset``."""
    items = []
    for name, (left, right, _) in loaded.items():
        npz = workdir / f"{name}.npz"
        np.savez(npz, left=left, right=right)
        items.append({"name": name, "npz": str(npz)})
    job, result = workdir / "job.json", workdir / "result.json"
    job.write_text(json.dumps({"pairs": items, "reps": reps}))
    runner = workdir / "runner.py"
    runner.write_text(LIBELAS_RUNNER)
    subprocess.run([python, str(runner), str(job), str(result)], check=True)
    out = {}
    for key, val in json.loads(result.read_text()).items():
        d = np.load(val["disp"])
        d[d < 0] = -1.0
        out[key] = (d, val["cpu_ms"] if cpu else val["ms"])
    return out


# ------------------------------------------------------------------ fresh start
FRESH = r'''
import time
t0 = time.perf_counter()
import numpy as np
from canopy_stereo.elas import elas_disparity
t1 = time.perf_counter()
data = np.load(__import__("sys").argv[1])
t2 = time.perf_counter()
elas_disparity(data["left"], data["right"], "robotics")
t3 = time.perf_counter()
elas_disparity(data["left"], data["right"], "middlebury", subpixel=True)
t4 = time.perf_counter()
print(f"{t1 - t0:.3f} {t3 - t2:.3f} {t4 - t3:.3f}")
'''


def fresh_process_times(left, right, workdir: Path) -> tuple[float, float, float]:
    npz = workdir / "fresh.npz"
    np.savez(npz, left=left, right=right)
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", FRESH, str(npz)], capture_output=True, text=True,
                         check=True, env=env).stdout.split()
    return tuple(float(x) for x in out)


def stage_times(left, right, params, *, reps: int, threads: int, right_map: bool) -> dict:
    """Median ms per stage (wall), and ``"total wall"`` / ``"total cpu"`` ms of whole
    :func:`~canopy_stereo.elas.core.elas_run` calls with ``threads`` numba threads."""
    import numba

    from canopy_stereo.elas.core import elas_run

    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        elas_run(left, right, params, want_right=right_map)
        stages: dict[str, list[float]] = {}
        wall, cpu = [], []
        for _ in range(reps):
            c0, t0 = time.process_time(), time.perf_counter()
            result = elas_run(left, right, params, want_right=right_map)
            wall.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            for name, sec in result.timings.items():
                stages.setdefault(name, []).append(sec)
    finally:
        numba.set_num_threads(before)
    out = {name: 1000 * float(np.median(v)) for name, v in stages.items()}
    out["total wall"] = 1000 * float(np.median(wall))
    out["total cpu"] = 1000 * float(np.median(cpu))
    return out


def stages_main(args) -> int:
    """``--stages``: per-stage ms of ELAS on one pair (see the module docstring)."""
    import numba

    from canopy_stereo.elas.params import make_params

    if args.left or args.right:
        if not (args.left and args.right):
            print("--stages needs both --left and --right (or neither, with --pairs)")
            return 2
        left, right = to_gray(read_image(args.left)), to_gray(read_image(args.right))
        name = Path(args.left).name
    else:
        pairs = selected_pairs(Path(args.data), args.pairs)
        if not pairs:
            print(f"no pair found (give --left/--right, or --pairs under {args.data})")
            return 1
        left, right, _ = load_pair(pairs[0])
        name = pairs[0]["name"]
    if args.scale != 1.0:
        size = (int(round(left.shape[1] * args.scale)), int(round(left.shape[0] * args.scale)))
        left, right = cv2.resize(left, size), cv2.resize(right, size)
    params = make_params(args.preset, disp_min=args.disp_min, disp_max=args.disp_max,
                         subsampling=args.subsampling)
    threads = [int(t) for t in args.threads.split(",")]
    threads = [t for t in threads if 1 <= t <= numba.config.NUMBA_NUM_THREADS] or [1]
    print(f"ELAS stages: {name} {left.shape[1]}x{left.shape[0]}, preset {args.preset}, "
          f"disparities {params.disp_min}..{params.disp_max}, "
          f"{'subsampling, ' if args.subsampling else ''}right map "
          f"{'on' if args.right_map else 'off'}, median of {args.reps} calls after a warm-up, "
          f"{os.cpu_count()} CPU(s)")
    results = {t: stage_times(left, right, params, reps=args.reps, threads=t,
                              right_map=args.right_map) for t in threads}
    names = list(dict.fromkeys(k for r in results.values() for k in r))
    header = f"{'stage':<22}" + "".join(f"{f'{t} thread(s)':>14}" for t in threads)
    print(header)
    print("-" * len(header))
    for stage in names:
        if stage.startswith("total"):
            print("-" * len(header))
        print(f"{stage + ' ms':<22}" + "".join(f"{results[t].get(stage, float('nan')):14.2f}"
                                             for t in threads))
    return 0


def cpu_ms(fn, reps: int) -> tuple[float, float]:
    """Median CPU ms (``time.process_time``: every thread of this process) and median wall
    ms of ``reps`` calls of ``fn`` after a warm-up call."""
    fn()
    cpu, wall = [], []
    for _ in range(reps):
        c, t = time.process_time(), time.perf_counter()
        fn()
        cpu.append(time.process_time() - c)
        wall.append(time.perf_counter() - t)
    return 1000 * float(np.median(cpu)), 1000 * float(np.median(wall))


def target_main(args) -> int:
    """``--target``: issue 28's ELAS targets. Per Middlebury 2014 training scene (quarter
    size, 640x480-class) and preset: this ELAS's CPU ms on one thread against libelas's
    (both ``time.process_time``, the same load), their ratio (target <= 0.3), and bad>2 and
    density against libelas's (target: within 0.2 points); then 1280x720 ms per frame on
    one and two threads (the first scene resized)."""
    import numba

    from canopy_stereo.elas import elas_disparity

    pairs = [p for p in selected_pairs(Path(args.data), args.pairs) if p["name"].endswith("Q")]
    pyelas = find_pyelas(args.pyelas)
    if not pairs or not pyelas:
        print("--target needs the MiddEval3 training scenes under --data and a Python with pyelas "
              "(--pyelas or $PYELAS_PYTHON; see elas.md)")
        return 1
    loaded = {p["name"]: load_pair(p) for p in pairs}
    presets = ("robotics", "middlebury")
    print(f"ELAS vs libelas ({pyelas}): median CPU ms of {args.reps} calls after a warm-up, "
          f"one thread, {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        libelas = run_libelas(pyelas, loaded, args.reps, Path(tmp), cpu=True)
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    header = (f"{'pair':<13}{'size':>9} {'preset':<11}{'cpu ms':>8}{'libelas':>9}{'ratio':>7}"
              f"{'bad>2':>7}{'(lib)':>7}{'d bad2':>8}{'density':>8}{'(lib)':>7}{'d dens':>8}")
    print(header)
    print("-" * len(header))
    summary: dict[str, list] = {preset: [] for preset in presets}
    try:
        for name, (left, right, gt) in loaded.items():
            for preset in presets:
                ours, _ = cpu_ms(lambda left=left, right=right, preset=preset: elas_disparity(
                    left, right, preset=preset, right_map=False), args.reps)
                disp = elas_disparity(left, right, preset=preset, right_map=False)[0]
                ref_disp, ref_ms = libelas[f"{name}/{preset}"]
                s, r = evaluate_disparity(disp, gt), evaluate_disparity(ref_disp, gt)
                d_bad, d_den = s.bad[2.0] - r.bad[2.0], s.density - r.density
                summary[preset].append((ours / ref_ms, d_bad, d_den))
                print(f"{name:<13}{left.shape[1]:>5}x{left.shape[0]:<4}{preset:<11}{ours:8.1f}"
                      f"{ref_ms:9.1f}{ours / ref_ms:7.3f}{s.bad[2.0]:7.2f}{r.bad[2.0]:7.2f}"
                      f"{d_bad:+8.2f}{s.density:8.1f}{r.density:7.1f}{d_den:+8.2f}")
    finally:
        numba.set_num_threads(before)
    print()
    for preset, rows in summary.items():
        ratio = np.array([r[0] for r in rows])
        within = sum(r[1] <= 0.2 and r[2] >= -0.2 for r in rows)
        print(f"{preset:<11} ratio median {np.median(ratio):.3f}, max {ratio.max():.3f}, "
              f"<= 0.3 on {int((ratio <= 0.3).sum())}/{len(rows)}; bad>2 and density within 0.2 "
              f"points of libelas (or better) on {within}/{len(rows)}; mean d bad2 "
              f"{np.mean([r[1] for r in rows]):+.2f}, mean d density {np.mean([r[2] for r in rows]):+.2f}")
    left, right, _ = next(iter(loaded.values()))
    left, right = cv2.resize(left, (1280, 720)), cv2.resize(right, (1280, 720))
    print(f"\n1280x720 ({next(iter(loaded))} resized), robotics, 0..255, left map only "
          "(as disparity_node), ms per frame (wall: loaded machine):")
    for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
        numba.set_num_threads(threads)
        try:
            cpu, wall = cpu_ms(lambda: elas_disparity(left, right, right_map=False), args.reps)
        finally:
            numba.set_num_threads(before)
        print(f"  {threads} thread(s): CPU {cpu:6.1f} ms, wall {wall:6.1f} ms")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(REPO.parent / "shared" / "data"))
    ap.add_argument("--pairs", default="", help="comma-separated names (default: all)")
    ap.add_argument("--reps", type=int, default=5, help="timed calls after the warm-up")
    ap.add_argument("--pyelas", default=None, help="a Python interpreter with pyelas")
    ap.add_argument("--no-fresh", action="store_true", help="skip the fresh-process timing")
    ap.add_argument("--stages", action="store_true",
                    help="per-stage ms and total CPU ms of ELAS alone on one pair")
    ap.add_argument("--left", default=None, help="--stages: left image (rectified)")
    ap.add_argument("--right", default=None, help="--stages: right image (rectified)")
    ap.add_argument("--preset", default="robotics", choices=["robotics", "middlebury"],
                    help="--stages: ELAS preset")
    ap.add_argument("--disp-min", type=int, default=0, help="--stages: smallest disparity")
    ap.add_argument("--disp-max", type=int, default=255, help="--stages: largest disparity")
    ap.add_argument("--scale", type=float, default=1.0, help="--stages: resize the pair first")
    ap.add_argument("--threads", default="1,2", help="--stages: numba thread counts to time")
    ap.add_argument("--right-map", action="store_true",
                    help="--stages: also post-process the right map (want_right)")
    ap.add_argument("--subsampling", action="store_true",
                    help="--stages: ELAS's subsampling (maps at every second row and column)")
    ap.add_argument("--target", action="store_true",
                    help="issue 28's targets: CPU ms against libelas on the MiddEval3 training "
                         "scenes (ratio, bad>2, density), 1280x720 on one and two threads")
    args = ap.parse_args(argv)
    if args.target:
        return target_main(args)
    if args.stages:
        return stages_main(args)

    import numba

    from canopy_stereo.elas import elas_disparity

    data = Path(args.data)
    pairs = selected_pairs(data, args.pairs)
    if not pairs:
        print(f"no ground-truth pairs found under {data}")
        return 1
    loaded = {p["name"]: load_pair(p) for p in pairs}
    print(f"ELAS benchmark: {len(pairs)} pairs, median of {args.reps} calls after a warm-up, "
          f"{numba.get_num_threads()} thread(s), {os.cpu_count()} CPU(s)")

    rows = []            # (pair, size, method, ms, scores)
    libelas = {}
    pyelas = find_pyelas(args.pyelas)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if pyelas:
            print(f"libelas: pyelas in {pyelas}")
            libelas = run_libelas(pyelas, loaded, args.reps, tmp)
        else:
            print("libelas: pyelas is absent (give --pyelas or $PYELAS_PYTHON); skipping it")
        for name, (left, right, gt) in loaded.items():
            size = f"{left.shape[1]}x{left.shape[0]}"
            for preset, sub in ELAS_CONFIGS:
                disp, sec = timed(lambda left=left, right=right, preset=preset, sub=sub: elas_disparity(
                    left, right, preset=preset, subpixel=sub, right_map=False)[0], args.reps)
                label = f"elas {preset}" + (" +subpix" if sub else "")
                rows.append((name, size, label, 1000 * sec, evaluate_disparity(disp, gt)))
            for preset in ("robotics", "middlebury"):
                if f"{name}/{preset}" in libelas:
                    disp, ms = libelas[f"{name}/{preset}"]
                    rows.append((name, size, f"libelas {preset}", ms,
                                 evaluate_disparity(disp, gt)))
            linear = elas_disparity(left, right, preset="robotics", adaptive_mean_weights="linear",
                                    right_map=False)[0]
            rows.append((name, size, "elas robotics linear-w", float("nan"),
                         evaluate_disparity(linear, gt)))
            dmax = int(np.ceil(np.nanmax(gt) / 16.0)) * 16
            disp, sec = timed(lambda left=left, right=right, dmax=dmax: sgbm(left, right, dmax), args.reps)
            rows.append((name, size, "opencv sgbm", 1000 * sec, evaluate_disparity(disp, gt)))
        fresh = None
        if not args.no_fresh:
            first = next(iter(loaded.values()))
            fresh = fresh_process_times(first[0], first[1], tmp)

    header = (f"{'pair':<13}{'size':>10}  {'method':<24}{'ms':>8}{'density%':>10}"
              f"{'bad>0.5%':>10}{'bad>1%':>8}{'bad>2%':>8}{'EPE':>7}")
    print()
    print(header)
    print("-" * len(header))
    last = None
    for name, size, method, ms, s in rows:
        if last is not None and name != last:
            print()
        last = name
        print(f"{name:<13}{size:>10}  {method:<24}{ms:8.1f}{s.density:10.1f}{s.bad[0.5]:10.2f}"
              f"{s.bad[1.0]:8.2f}{s.bad[2.0]:8.2f}{s.epe:7.3f}")

    by = {(r[0], r[2]): r for r in rows}
    if libelas:
        print("\nTargets against libelas (bad>2 <= +0.5, density >= -1, time <= libelas):")
        n_ok = n_all = 0
        for name in loaded:
            for preset in ("robotics", "middlebury"):
                ours, ref = by[(name, f"elas {preset}")], by.get((name, f"libelas {preset}"))
                if ref is None:
                    continue
                d_bad = ours[4].bad[2.0] - ref[4].bad[2.0]
                d_den = ours[4].density - ref[4].density
                ok = (d_bad <= 0.5, d_den >= -1.0, ours[3] <= ref[3])
                n_ok += all(ok)
                n_all += 1
                flags = " ".join(f"{k}:{'ok' if v else 'MISS'}" for k, v in
                                 zip(("bad>2", "density", "time"), ok))
                print(f"  {name:<13}{preset:<11} bad>2 {d_bad:+5.2f}  density {d_den:+5.2f}  "
                      f"time {ours[3]:7.1f} vs {ref[3]:7.1f} ms   {flags}")
        print(f"  {n_ok}/{n_all} pair-presets meet all three")

    print("\nSub-pixel refinement (mean over pairs; EPE px, bad>0.5 %):")
    for preset in ("robotics", "middlebury"):
        plain = [by[(n, f"elas {preset}")][4] for n in loaded]
        refined = [by[(n, f"elas {preset} +subpix")][4] for n in loaded]
        print(f"  {preset:<11} EPE {np.mean([s.epe for s in plain]):.3f} -> "
              f"{np.mean([s.epe for s in refined]):.3f}   bad>0.5 "
              f"{np.mean([s.bad[0.5] for s in plain]):.2f} -> "
              f"{np.mean([s.bad[0.5] for s in refined]):.2f}   bad>2 "
              f"{np.mean([s.bad[2.0] for s in plain]):.2f} -> "
              f"{np.mean([s.bad[2.0] for s in refined]):.2f}")
    step = [by[(n, "elas robotics")][4] for n in loaded]
    lin = [by[(n, "elas robotics linear-w")][4] for n in loaded]
    print("\nAdaptive mean weights, robotics (mean over pairs): as compiled (4/2/0) vs "
          "intended max(0, 4-|dd|):")
    print(f"  EPE {np.mean([s.epe for s in step]):.3f} vs {np.mean([s.epe for s in lin]):.3f}   "
          f"bad>1 {np.mean([s.bad[1.0] for s in step]):.2f} vs "
          f"{np.mean([s.bad[1.0] for s in lin]):.2f}   bad>2 "
          f"{np.mean([s.bad[2.0] for s in step]):.2f} vs {np.mean([s.bad[2.0] for s in lin]):.2f}")
    if fresh:
        print(f"\nFresh process (cache warm): import {fresh[0]:.2f} s, first call "
              f"{fresh[1]:.2f} s (robotics), first middlebury+subpixel call {fresh[2]:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
