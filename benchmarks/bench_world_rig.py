"""Benchmark: world-rig calibration accuracy against the number of placements and corner noise.

The paper's rig (config/paper_rig.yaml, 640x480) photographs its 7x5 board of 50 mm
squares at the places of the paper's layout (three lines at -10, 0, +10 degrees, 15
marks each), rendered with 0.7 px blur. Every view is ray-cast ONCE; each image-noise
level is then applied to the same radiance, the corners are detected, and the rig is
calibrated from 9, 15, 30 and 45 placements (evenly spread over the three lines).

Per row: image noise (grey levels), placements, mean corner error against the true
projections (px), the rig's reprojection RMS (px, mean of both cameras), the mean absolute
error of 9x9x9 points of the working volume (the box the 45 boards span) seen exactly
and triangulated with the recovered matrices (mm, X/Y/Z; the issue's target <= 0.2 / 0.2
/ 0.5 mm), the paper's Table 1 (leave-one-placement-out, detected corners triangulated
back, mean absolute error X/Y/Z in mm; the paper: 0.42 / 0.36 / 2.78), and the time of
the calibration (detection excluded).

A second table adds Gaussian noise of a given sigma (px per coordinate) to the exact
corner projections (no rendering): the corner-noise sensitivity of the Gold Standard.

    .venv/bin/python benchmarks/bench_world_rig.py [--image-noise 0,2,4] [--samples 16]
        [--counts 9,15,30,45] [--corner-noise 0.02,0.05,0.1,0.2] [--json out.json]

Rendering 90 views takes a few minutes on 2 cores (16 anti-aliasing rays per pixel).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from canopy_stereo.geometry.board_corners import detect_board_corners  # noqa: E402
from canopy_stereo.geometry.board_placements import board_world_points  # noqa: E402
from canopy_stereo.geometry.camera import camera_centre, project  # noqa: E402
from canopy_stereo.geometry.triangulation import triangulate_dlt  # noqa: E402
from canopy_stereo.geometry.world_rig import calibrate_world_rig  # noqa: E402
from canopy_stereo.sim import resolve_rig  # noqa: E402


def spread(count: int, per_line: int = 15, lines: int = 3) -> list[int]:
    """``count`` pair indices spread evenly over the lines and along each line."""
    per = [count // lines + (1 if k < count % lines else 0) for k in range(lines)]
    out = []
    for line, n in enumerate(per):
        marks = np.unique(np.round(np.linspace(0, per_line - 1, n)).astype(int))
        out += [line * per_line + int(m) for m in marks]
    return out


def volume_error(rig, P_left, P_right, X_all) -> np.ndarray:
    """(3,) mean absolute X/Y/Z error of a 9x9x9 grid over the box of ``X_all``."""
    lo, hi = X_all.min(0), X_all.max(0)
    g = np.stack(np.meshgrid(*[np.linspace(lo[i], hi[i], 9) for i in range(3)], indexing="ij"),
                 -1).reshape(-1, 3)
    est = triangulate_dlt(P_left, P_right, project(rig.P_left, g), project(rig.P_right, g), drop_behind=False)
    return np.abs(est - g).mean(axis=0)


def render_corners(rig, placements, noise_levels, samples: int, blur: float, seed: int):
    """``{noise: {pair: (left corners | None, right corners | None)}}``, each view ray-cast once."""
    import cv2

    from canopy_stereo.sim.calibration import _coprime_generator, calibration_scene
    from canopy_stereo.sim.render import render_view
    from canopy_stereo.sim.sensor import CameraEffects, lattice_pattern

    pattern = lattice_pattern(samples, _coprime_generator(samples))
    out = {n: {} for n in noise_levels}
    t0 = time.perf_counter()
    for i, p in enumerate(placements):
        scene = calibration_scene(rig, p, placements)
        rads = []
        for P, D in ((rig.P_left, rig.D_left), (rig.P_right, rig.D_right)):
            r = render_view(scene, P, D, rig.image_size, samples=pattern).radiance
            rads.append(cv2.GaussianBlur(r, (0, 0), blur) if blur > 0 else r)
        for n in noise_levels:
            rng = np.random.default_rng([seed, p.pair, int(n * 100)])
            eff = CameraEffects(noise_sigma=float(n))
            views = [detect_board_corners(eff.expose(rads[c], c, rng), placements.pattern) for c in (0, 1)]
            out[n][p.pair] = tuple(views)
        print(f"\r  rendered {i + 1}/{len(placements)} pairs ({time.perf_counter() - t0:.0f} s)",
              end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return out, time.perf_counter() - t0


def corner_error(rig, placements, det) -> float:
    errs = []
    for p in placements:
        W = board_world_points(p, placements.pattern, placements.square)
        for c, P in zip(det[p.pair], (rig.P_left, rig.P_right)):
            if c is None:
                continue
            x = project(P, W)
            errs.append(min(np.sqrt(np.mean(np.sum((c - x) ** 2, 1))),
                            np.sqrt(np.mean(np.sum((c[::-1] - x) ** 2, 1)))))
    return float(np.mean(errs))


def calibrate_subset(rig, placements, det, idx, X_all):
    sub = placements.subset(idx)
    sub_det = {k: det[pair] for k, pair in enumerate(idx)}
    blank = [None] * len(idx)
    t0 = time.perf_counter()
    cal = calibrate_world_rig(blank, blank, sub, detections=sub_det, image_size=rig.image_size)
    dt = time.perf_counter() - t0
    vol = volume_error(rig, cal.P_left, cal.P_right, X_all)
    dc = max(np.linalg.norm(camera_centre(cal.P_left) - camera_centre(rig.P_left)),
             np.linalg.norm(camera_centre(cal.P_right) - camera_centre(rig.P_right)))
    return cal, vol, dc, dt


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--image-noise", default="0,2,4", help="sensor noise sigmas, grey levels")
    parser.add_argument("--counts", default="9,15,30,45", help="numbers of placements")
    parser.add_argument("--corner-noise", default="0.02,0.05,0.1,0.2",
                        help="corner noise sigmas (px per coordinate) of the synthetic table")
    parser.add_argument("--samples", type=int, default=16, help="anti-aliasing rays per pixel")
    parser.add_argument("--blur", type=float, default=0.7, help="optical blur sigma, px")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    args = parser.parse_args(argv)
    noise_levels = [float(v) for v in args.image_noise.split(",") if v.strip()]
    counts = [int(v) for v in args.counts.split(",") if v.strip()]
    corner_noise = [float(v) for v in args.corner_noise.split(",") if v.strip()]

    from canopy_stereo.sim.calibration import calibration_placements

    rig = resolve_rig(None)
    placements = calibration_placements(rig)
    X_all = np.vstack([board_world_points(p, placements.pattern, placements.square) for p in placements])
    print(f"paper rig 640x480, paper layout ({len(placements)} placements, 7x5 board, 50 mm), blur "
          f"{args.blur} px, {args.samples} rays/px; {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.1f}")
    results = {"rendered": [], "synthetic": []}
    if noise_levels:
        det_all, render_s = render_corners(rig, placements, noise_levels, args.samples, args.blur, args.seed)
        print(f"rendering + detection: {render_s:.0f} s for {2 * len(placements)} views x "
              f"{len(noise_levels)} noise levels")
        head = (f"{'noise DN':>8} {'pairs':>5} {'corner px':>9} {'rms px':>7} {'volume X/Y/Z mm':>21} "
                f"{'Table 1 X/Y/Z mm (LOO)':>24} {'centre mm':>9} {'calib s':>7}")
        print("\nrendered images (working volume target <= 0.2 / 0.2 / 0.5 mm; paper Table 1 0.42 / 0.36 / 2.78)")
        print(head)
        for n in noise_levels:
            det = det_all[n]
            cerr = corner_error(rig, placements, det)
            for count in counts:
                idx = spread(count)
                cal, vol, dc, dt = calibrate_subset(rig, placements, det, idx, X_all)
                t1 = cal.table1.mean_abs
                rms = 0.5 * (cal.rms_left + cal.rms_right)
                print(f"{n:>8g} {len(cal.used_pairs):>5} {cerr:>9.4f} {rms:>7.4f} "
                      f"{vol[0]:>6.3f} {vol[1]:>6.3f} {vol[2]:>7.3f} {t1[0]:>7.3f} {t1[1]:>7.3f} {t1[2]:>8.3f} "
                      f"{dc:>9.3f} {dt:>7.2f}")
                results["rendered"].append({
                    "image_noise": n, "placements": len(cal.used_pairs), "corner_error_px": cerr,
                    "rms_px": rms, "volume_mae_mm": vol.tolist(), "table1_mae_mm": t1.tolist(),
                    "table1_std_mm": cal.table1.std.tolist(), "centre_error_mm": dc, "calibration_s": dt})
    print("\nsynthetic corners: exact projections + Gaussian noise (px per coordinate)")
    print(f"{'sigma px':>8} {'pairs':>5} {'rms px':>7} {'volume X/Y/Z mm':>21} {'Table 1 X/Y/Z mm (LOO)':>24}")
    rng = np.random.default_rng(args.seed)
    for sigma in corner_noise:
        det = {}
        for p in placements:
            W = board_world_points(p, placements.pattern, placements.square)
            det[p.pair] = tuple(project(P, W) + rng.normal(0, sigma, (len(W), 2))
                                for P in (rig.P_left, rig.P_right))
        for count in counts:
            cal, vol, dc, dt = calibrate_subset(rig, placements, det, spread(count), X_all)
            t1 = cal.table1.mean_abs
            rms = 0.5 * (cal.rms_left + cal.rms_right)
            print(f"{sigma:>8g} {len(cal.used_pairs):>5} {rms:>7.4f} {vol[0]:>6.3f} {vol[1]:>6.3f} "
                  f"{vol[2]:>7.3f} {t1[0]:>7.3f} {t1[1]:>7.3f} {t1[2]:>8.3f}")
            results["synthetic"].append({"corner_sigma_px": sigma, "placements": count, "rms_px": rms,
                                         "volume_mae_mm": vol.tolist(), "table1_mae_mm": t1.tolist()})
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
