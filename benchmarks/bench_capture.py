"""Benchmark: real capture on a moving robot -- skew, speed, direction, wind, MJPEG -- with truth.

Renders field sequences of the simulator (:mod:`canopy_stereo.sim.sequence`: the croton
through the paper's 640x480 rig at 15 frames/s, the right camera ``skew`` ms late) and
reconstructs the second frame of each with ELAS, as it comes and with the skew
compensation every entry point applies (:class:`canopy_stereo.skew.SkewCompensator`,
default settings), against the truth of the left capture instant:

* depth: median relative depth error of the leaf pixels (left camera axis);
* density: share of the leaf pixels that got a point;
* leaf size: mean over the two marked leaves of the median ``|d / d_true - 1|`` of the
  distances between random pairs of a leaf's reconstructed pixels at least a third of its
  length apart: the scale and row errors the measuring stage inherits (not the measuring
  stage itself);
* CPU: milliseconds the compensation adds per pair (wall and process CPU time, median of
  repeated runs on the sequence's frames), per DIS preset.

Sweeps: skew 0-33 ms (along the baseline, 0.25 m/s), speed 0.05-0.5 m/s (16 ms),
direction (along, across, toward, turning; 0.25 m/s or 20 deg/s, 8 ms), wind (still rig,
16 ms; leaf speeds printed), JPEG quality (95, 80, 60; 0.25 m/s, 8 ms). The graph's clouds/s
with compressed inputs is benchmarks/bench_graph.py's (issue 24 item 1).

    .venv/bin/python benchmarks/bench_capture.py [--quick] [--scale 0.5] [--sweeps skew speed ...]

Figures measured on a loaded machine are only indicative of the CPU cost.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canopy_stereo.pipeline.reconstruct import reconstruct_pair  # noqa: E402
from canopy_stereo.sim import resolve_rig, rig_at_resolution  # noqa: E402
from canopy_stereo.sim.sequence import (  # noqa: E402
    CaptureTiming,
    RigMotion,
    SequenceSpec,
    depth_accuracy,
    render_sequence,
)
from canopy_stereo.skew import SkewCompensator  # noqa: E402

#: sweep -> cases ``(label, direction, speed m/s, turn deg/s, skew ms, wind, JPEG quality)``.
SWEEPS = {
    "skew": [(f"skew {s} ms", "along", 0.25, 0.0, s, 0.0, None) for s in (0, 8, 16, 33)],
    "speed": [(f"speed {v} m/s", "along", v, 0.0, 16, 0.0, None) for v in (0.05, 0.1, 0.25, 0.5)],
    "direction": [("along", "along", 0.25, 0.0, 8, 0.0, None), ("across", "across", 0.25, 0.0, 8, 0.0, None),
                  ("toward", "toward", 0.25, 0.0, 8, 0.0, None),
                  ("turning 20 deg/s", "still", 0.0, 20.0, 8, 0.0, None)],
    "wind": [(f"wind {w}", "still", 0.0, 0.0, 16, w, None) for w in (1.0, 3.0, 5.0)],
    "jpeg": [(f"JPEG {q}", "along", 0.25, 0.0, 8, 0.0, q) for q in (95, 80, 60)],
}
QUICK = {"skew": [0, 2], "speed": [3], "direction": [1], "wind": [1], "jpeg": [1]}


def leaf_size_error(frame, organized, *, pairs: int = 4000) -> float:
    """Mean over the marked leaves of the median ``|d / d_true - 1|`` of distances between
    random pairs of the leaf's reconstructed pixels at least a third of its length apart."""
    rng = np.random.default_rng(0)
    errors = []
    for lf in frame.truth["leaves"]:
        if not lf["marked"]:
            continue
        px = (frame.leaf_ids_left == lf["id"]) & np.all(np.isfinite(organized), axis=2)
        if px.sum() < 50:
            continue
        got, true = organized[px], frame.xyz_left[px]
        i, j = rng.integers(0, len(got), (2, pairs))
        d_true = np.linalg.norm(true[i] - true[j], axis=1)
        far = d_true > lf["length"] / 3
        if far.sum() < 20:
            continue
        d = np.linalg.norm(got[i] - got[j], axis=1)
        errors.append(float(np.median(np.abs(d[far] / d_true[far] - 1.0))))
    return float(np.mean(errors)) if errors else float("nan")


def run_case(rig, case, *, supersample: int) -> dict:
    label, direction, speed, turn, skew_ms, wind, quality = case
    spec = SequenceSpec(scene="croton", frames=2, motion=RigMotion(direction, speed, turn),
                        timing=CaptureTiming(fps=15.0, skew=skew_ms / 1e3), wind=wind, jpeg_quality=quality,
                        supersample=supersample)
    t0 = time.perf_counter()
    frames = list(render_sequence(spec, rig))
    render_s = time.perf_counter() - t0
    comp = SkewCompensator()
    for f in frames:
        left, right, rep = comp.compensate(f.left, f.right, stamp_left_ns=round(f.t_left * 1e9),
                                           stamp_right_ns=round(f.t_right * 1e9))
    f = frames[-1]
    out = {"case": label, "render_s": render_s, "applied": rep.applied, "reason": rep.reason,
           "shift_px": rep.shift_px, "leaf_speed_mm_s": f.truth["leaf_speed_mm_s"]["median"]}
    for name, (l_img, r_img) in (("raw", (f.left, f.right)), ("comp", (left, right))):
        if name == "comp" and not rep.applied:
            out.update({f"{k}_comp": out[f"{k}_raw"] for k in ("depth", "density", "leaf")})
            continue
        organized = reconstruct_pair(l_img, r_img, rig).organized
        err, density = depth_accuracy(f, organized, rig)
        out[f"depth_{name}"], out[f"density_{name}"] = err, density
        out[f"leaf_{name}"] = leaf_size_error(f, organized)
    out["frames"] = frames
    return out


def cost_ms(frames, *, preset: str, repeat: int) -> tuple[float, float]:
    """Median wall and process-CPU ms of one compensation on the frames' second pair."""
    prev, cur = frames
    walls, cpus = [], []
    comp = SkewCompensator(flow_preset=preset)
    for _ in range(repeat):
        comp.observe(prev.right, stamp_right_ns=round(prev.t_right * 1e9))
        c0, t0 = time.process_time(), time.perf_counter()
        comp.compensate(cur.left, cur.right, stamp_left_ns=round(cur.t_left * 1e9),
                        stamp_right_ns=round(cur.t_right * 1e9))
        walls.append(1e3 * (time.perf_counter() - t0))
        cpus.append(1e3 * (time.process_time() - c0))
    return statistics.median(walls), statistics.median(cpus)


def preset_error(rig, frames, preset: str) -> float:
    comp = SkewCompensator(flow_preset=preset)
    for f in frames:
        left, right, _ = comp.compensate(f.left, f.right, stamp_left_ns=round(f.t_left * 1e9),
                                         stamp_right_ns=round(f.t_right * 1e9))
    return depth_accuracy(frames[-1], reconstruct_pair(left, right, rig).organized, rig)[0]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sweeps", nargs="*", choices=list(SWEEPS), default=list(SWEEPS))
    p.add_argument("--quick", action="store_true", help="a few cases per sweep (about a minute)")
    p.add_argument("--scale", type=float, default=1.0, help="image scale of the paper rig (0.5: 320x240)")
    p.add_argument("--supersample", type=int, default=2)
    p.add_argument("--repeat", type=int, default=15, help="timed compensations per preset")
    p.add_argument("--json", metavar="OUT.json", help="also write the figures as JSON")
    args = p.parse_args(argv)

    rig = resolve_rig(None)
    if args.scale != 1.0:
        rig = rig_at_resolution(rig, args.scale)
    w, h = rig.image_size
    print(f"croton through the paper rig at {w}x{h}, 15 frames/s, ELAS; {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.1f} (a loaded machine: timings are indicative)")
    head = (f"{'case':<18}{'depth raw':>10}{'comp':>7}{'dens raw':>10}{'comp':>7}{'leaf raw':>10}{'comp':>7}"
            f"{'shift px':>9}{'leaf mm/s':>10}  note")
    results, timing_frames = [], None
    t_start = time.perf_counter()
    for sweep in args.sweeps:
        cases = SWEEPS[sweep]
        if args.quick:
            cases = [cases[i] for i in QUICK[sweep]]
        print(f"\n== {sweep} ==\n{head}")
        for case in cases:
            r = run_case(rig, case, supersample=args.supersample)
            if timing_frames is None and r["applied"]:
                timing_frames = r["frames"]
            del r["frames"]
            r["sweep"] = sweep
            results.append(r)
            note = "" if r["applied"] else f"not compensated: {r['reason']}"
            print(f"{r['case']:<18}{100 * r['depth_raw']:>9.2f}%{100 * r['depth_comp']:>6.2f}%"
                  f"{100 * r['density_raw']:>9.1f}%{100 * r['density_comp']:>6.1f}%"
                  f"{100 * r['leaf_raw']:>9.1f}%{100 * r['leaf_comp']:>6.1f}%{r['shift_px']:>9.2f}"
                  f"{r['leaf_speed_mm_s']:>10.0f}  {note}", flush=True)
    costs = {}
    if timing_frames is not None:
        print("\n== CPU added per pair (the compensation alone; DIS presets) ==")
        print(f"{'preset':<10}{'wall ms':>9}{'cpu ms':>8}{'depth err (that pair)':>23}")
        for preset in ("ultrafast", "fast", "medium"):
            wall, cpu = cost_ms(timing_frames, preset=preset, repeat=args.repeat)
            err = preset_error(rig, timing_frames, preset)
            costs[preset] = {"wall_ms": wall, "cpu_ms": cpu, "depth_error": err}
            default = " (default)" if preset == SkewCompensator().flow_preset else ""
            print(f"{preset:<10}{wall:>9.1f}{cpu:>8.1f}{100 * err:>22.2f}%{default}")
    print(f"\n{len(results)} cases in {time.perf_counter() - t_start:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"rig": [w, h], "cases": results, "cost": costs}, indent=1,
                                              default=float), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
