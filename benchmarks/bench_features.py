"""Feature-matching benchmark (issue 6): qdmatch speed, spread, correctness and Hartley.

Prints:

1. qdmatch stage times on 640x480 pairs (synthetic croton, a raw chessboard pair)
   and Plants (710x496), ONE thread (OpenCV and numba limited to one core),
   median of 3 runs after a warm-up: process CPU time of the whole call (robust on
   a shared machine) and wall-clock stage times. Target: < 1.5 s per pair.
2. Distribution (share of 8x8-pixel cells with a match) on the plant scenes
   (Aloe, Plants, Flowerpots, croton, citrus branch), qdmatch before issue 18 (no
   reseeding, Lhuillier & Quan's centre-only resampling), with reseeding and relaxed
   resampling but without the aperture/interior checks, qdmatch now, SIFT and
   ASIFT, with the share of *textured* cells reached (mean gradient magnitude above
   3 grey levels per pixel: leaves, pots, edges; not walls) and the share correct
   (ground truth where it exists, else the epipolar line). Target: qdmatch 27-31 %
   (the paper's), >= 95 % correct.
3. Correct matches (disparity within 1 px of the ground truth, rows within 1 px) on
   every Middlebury GT scene in ../shared/data, qdmatch (before / reseeding without the
   checks / now) vs SIFT, and on
   croton against the simulator's exact correspondences. Target: qdmatch >= 95 %.
4. Hartley rectification from qdmatch matches on the 13 raw chessboard pairs:
   median |v_left - v_right| of the rectified board corners (target <= 0.5 px),
   per pair and with the matches of all pairs pooled (one fixed rig), matches and
   corners undistorted with a calibration of the same images.
5. With ``--study``: the full study table (all methods) for Aloe, Plants, croton.

Run: ``.venv/bin/python benchmarks/bench_features.py [--study] [--data ../shared/data]``
"""
from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from canopy_stereo.features import match_pair  # noqa: E402
from canopy_stereo.features.study import format_table, gt_correctness, run_study  # noqa: E402
from canopy_stereo.io.images import read_image  # noqa: E402
from canopy_stereo.io.middlebury import read_disparity  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

GT_SCENES = {
    "Tsukuba": ("middlebury2001/Tsukuba", "imL.png", "imR.png", "truedisp.pgm", 16),
    "Venus": ("middlebury2001/Venus", "imL.png", "imR.png", "disp2.pgm", 8),
    "Cones": ("middlebury2003_quartersize/Cones", "imL.png", "imR.png", "disp2.png", 4),
    "Teddy": ("middlebury2003_quartersize/Teddy", "imL.png", "imR.png", "disp2.png", 4),
    "Aloe": ("middlebury2006_thirdsize/Aloe", "view1.png", "view5.png", "disp1.png", 3),
    "Flowerpots": ("middlebury2006_thirdsize/Flowerpots", "view1.png", "view5.png", "disp1.png", 3),
}
for _s in ("Adirondack", "ArtL", "Motorcycle", "Piano", "Playtable", "Recycle", "Shelves", "Teddy",
           "Vintage"):
    GT_SCENES[f"Q{_s}"] = (f"middlebury_MiddEval3_trainingQ/{_s}", "im0.png", "im1.png",
                           "disp0GT.pfm", None)


#: qdmatch without issue 18's correctness checks (no aperture limit, no interior check,
#: 1-px epipolar band, the earlier resampling thresholds).
_NO_CHECKS = dict(aperture_max=None, anchor_aperture_max=None, interior_px=0, epipolar_band_px=1.0,
                  few_seeds_band_px=1.0, texture_min=2.0, min_support=12, min_inlier_share=0.85)
#: qdmatch as it was before issue 18: SIFT seeds only, Lhuillier & Quan's resampling
#: (cell centre only when surrounded, every region spread >= 1.8 px).
QDMATCH_BEFORE = dict(_NO_CHECKS, reseed_rounds=0, anchor="centre", min_spread_px=1.8,
                      thin_spread_px=1.8)
#: qdmatch with issue 18's reseeding and relaxed resampling but without its checks
#: (Plants 25.2 % of cells, Middlebury 90.7 % correct).
QDMATCH_RESEED_ONLY = dict(_NO_CHECKS, min_spread_px=1.4, thin_spread_px=0.0)


def rendered(scene="croton"):
    """(left, right, true right pixel per left pixel (H, W, 2) NaN where unknown/occluded)."""
    from canopy_stereo.sim import render_scene
    from canopy_stereo.sim.correspondence import true_right_pixels

    sim = render_scene(scene)
    return sim.left, sim.right, true_right_pixels(sim)


def croton():
    return rendered("croton")


def croton_correctness(res, truth):
    from canopy_stereo.features.study import correspondence_correctness

    return correspondence_correctness(res.x_left, res.x_right, truth)


def textured_cells(gray, gradient_min=3.0, cell=8):
    """(ny, nx) bool: cells whose mean gradient magnitude (Gaussian sigma 1 px) exceeds
    ``gradient_min`` grey levels per pixel (leaves, pots, edges; not walls or table tops)."""
    g = cv2.GaussianBlur(np.asarray(gray, np.float64), (0, 0), 1.0)
    mag = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0, ksize=3), cv2.Sobel(g, cv2.CV_64F, 0, 1, ksize=3)) / 8
    h, w = mag.shape
    ny, nx = -(-h // cell), -(-w // cell)
    pad = np.zeros((ny * cell, nx * cell))
    pad[:h, :w] = mag
    return pad.reshape(ny, cell, nx, cell).mean(axis=(1, 3)) > gradient_min


def reached(x_left, cells, cell=8):
    """Share of the ``cells`` (bool (ny, nx)) holding a match."""
    if not cells.any():
        return float("nan")
    x = np.asarray(x_left, np.float64).reshape(-1, 2)
    cx = np.clip(np.floor((x[:, 0] + 0.5) / cell).astype(int), 0, cells.shape[1] - 1)
    cy = np.clip(np.floor((x[:, 1] + 0.5) / cell).astype(int), 0, cells.shape[0] - 1)
    used = np.zeros_like(cells)
    used[cy, cx] = True
    return float((used & cells).sum() / cells.sum())


def load_gt_scene(data: Path, name: str):
    folder, left, right, truth, scale = GT_SCENES[name]
    return (read_image(data / folder / left), read_image(data / folder / right),
            read_disparity(data / folder / truth, scale))


def bench_speed(pairs):
    print("1. qdmatch on one core (median of 3 after a warm-up)")
    cv2.setNumThreads(1)
    for name, (left, right) in pairs.items():
        match_pair(left, right, method="qdmatch")
        runs = []
        for _ in range(3):
            t, c = time.perf_counter(), time.process_time()
            res = match_pair(left, right, method="qdmatch", min_matches=0)
            runs.append((time.process_time() - c, time.perf_counter() - t, res))
        cpu, total, res = sorted(runs, key=lambda x: x[0])[1]
        h, w = left.shape[:2]
        print(f"   {name:<12} {w}x{h}: CPU {cpu:.3f} s, wall {total:.3f} s (wall: sift left "
              f"{res.t_left:.3f} + right "
              f"{res.t_right:.3f}, seed matching {res.t_match:.3f}, propagation "
              f"{res.t_propagation:.3f}, resample {res.t_resample:.3f}); "
              f"{res.extras['num_seeds']} seeds -> {res.extras['num_propagated']} propagated -> "
              f"{res.num} matches")
    cv2.setNumThreads(-1)


def bench_spread(plant_pairs, asift=True):
    """plant_pairs: name -> (left, right, truth kind, truth) with kind "disp", "pixels" or None."""
    from canopy_stereo.features.study import correspondence_correctness, epipolar_correctness
    from canopy_stereo.io.images import to_gray

    print("2. distribution on plant scenes: cells with a match % (textured cells reached %, "
          "correct %) [matches]; target qdmatch 27-31 % (paper), >= 95 % correct")
    variants = [("sift", "sift", {}), ("qdmatch before", "qdmatch", QDMATCH_BEFORE),
                ("qdmatch reseed only", "qdmatch", QDMATCH_RESEED_ONLY),
                ("qdmatch", "qdmatch", {})] + ([("asift", "asift", {})] if asift else [])
    for name, (left, right, kind, truth) in plant_pairs.items():
        cells = textured_cells(to_gray(left))
        results = [(label, match_pair(left, right, method=m, min_matches=0, **kw)) for label, m, kw in variants]
        if kind is None:
            shares, _ = epipolar_correctness([r for _, r in results])
        parts = []
        for k, (label, r) in enumerate(results):
            if kind == "disp":
                c, _ = gt_correctness(r.x_left, r.x_right, truth)
            elif kind == "pixels":
                c, _ = correspondence_correctness(r.x_left, r.x_right, truth)
            else:
                c = shares[k]
            cs = "-" if c is None else f"{100 * c:.1f}"
            parts.append(f"{label} {100 * r.distribution:5.1f} % ({100 * reached(r.x_left, cells):4.1f}, "
                         f"{cs}) [{r.num}]")
        basis = {"disp": "GT", "pixels": "exact", None: "epipolar"}[kind]
        print(f"   {name:<12} ({basis:>8}, textured cells {100 * cells.mean():4.1f} %): " + "   ".join(parts))


def bench_correctness(data: Path, croton_pair):
    print("3. correct matches (|d - d_gt| <= 1 px and |dv| <= 1 px; target qdmatch >= 95 %)")
    shares, before_shares, reseed_shares = [], [], []
    for name in GT_SCENES:
        left, right, gt = load_gt_scene(data, name)
        s = match_pair(left, right, method="sift")
        q = match_pair(left, right, method="qdmatch")
        b = match_pair(left, right, method="qdmatch", min_matches=0, **QDMATCH_BEFORE)
        o = match_pair(left, right, method="qdmatch", min_matches=0, **QDMATCH_RESEED_ONLY)
        cs, _ = gt_correctness(s.x_left, s.x_right, gt)
        cq, n = gt_correctness(q.x_left, q.x_right, gt)
        cb, _ = gt_correctness(b.x_left, b.x_right, gt)
        co, _ = gt_correctness(o.x_left, o.x_right, gt)
        shares.append(cq)
        before_shares.append(cb)
        reseed_shares.append(co)
        print(f"   {name:<12} sift {100 * cs:5.1f} % of {s.num:4d} ({100 * s.distribution:4.1f} %)   "
              f"qdmatch {100 * cq:5.1f} % of {n:4d} with GT (distribution {100 * q.distribution:4.1f} %; "
              f"before issue 18: {100 * cb:5.1f} % at {100 * b.distribution:4.1f} %; reseeding "
              f"without checks: {100 * co:5.1f} % at {100 * o.distribution:4.1f} %)")
    for label, sh in (("now", shares), ("before issue 18", before_shares),
                      ("reseeding without checks", reseed_shares)):
        print(f"   Middlebury ({label}) mean {100 * np.mean(sh):.1f} %, median {100 * np.median(sh):.1f} %, "
              f"min {100 * np.min(sh):.1f} %, scenes >= 95 %: {sum(c >= 0.95 for c in sh)}/{len(sh)}")
    left, right, truth = croton_pair
    for m in ("sift", "qdmatch"):
        res = match_pair(left, right, method=m)
        c, n = croton_correctness(res, truth)
        print(f"   croton (simulated, unrectified) {m}: {100 * c:.1f} % of {n} within 1 px of the "
              f"true right pixel")


def bench_hartley(data: Path):
    from canopy_stereo.geometry.rectification import hartley_rectify
    from canopy_stereo.geometry.triangulation import apply_homography

    print("4. Hartley rectification from qdmatch on raw chessboard pairs "
          "(median |v_left - v_right| of corners, target <= 0.5 px)")
    folder = data / "opencv_stereo_calib_chessboard"
    ids = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
    pairs, cl_all, cr_all = [], [], []
    for i in ids:
        L = read_image(folder / f"left{i:02d}.jpg", color=False)
        R = read_image(folder / f"right{i:02d}.jpg", color=False)
        _, cl = cv2.findChessboardCorners(L, (9, 6))
        _, cr = cv2.findChessboardCorners(R, (9, 6))
        cl_all.append(cv2.cornerSubPix(L, cl, (11, 11), (-1, -1), crit))
        cr_all.append(cv2.cornerSubPix(R, cr, (11, 11), (-1, -1), crit))
        pairs.append((L, R))
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    objs = [obj] * len(ids)
    _, K1, D1, _, _ = cv2.calibrateCamera(objs, cl_all, (640, 480), None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera(objs, cr_all, (640, 480), None, None)

    def und(x, K, D):
        return cv2.undistortPoints(np.asarray(x, np.float64).reshape(-1, 1, 2), K, D, P=K).reshape(-1, 2)

    matches = [match_pair(L, R, method="qdmatch") for L, R in pairs]
    for undistort in (False, True):
        def pts(x, K, D, undistort=undistort):
            return und(x, K, D) if undistort else np.asarray(x, np.float64).reshape(-1, 2)

        per_pair = []
        for m, cl, cr in zip(matches, cl_all, cr_all):
            rect = hartley_rectify(pts(m.x_left, K1, D1), pts(m.x_right, K2, D2), (640, 480))
            dv = apply_homography(rect.H_left, pts(cl, K1, D1))[:, 1] - \
                apply_homography(rect.H_right, pts(cr, K2, D2))[:, 1]
            per_pair.append(float(np.median(np.abs(dv))))
        xl = np.vstack([pts(m.x_left, K1, D1) for m in matches])
        xr = np.vstack([pts(m.x_right, K2, D2) for m in matches])
        rect = hartley_rectify(xl, xr, (640, 480))
        dv = np.concatenate([apply_homography(rect.H_left, pts(cl, K1, D1))[:, 1]
                             - apply_homography(rect.H_right, pts(cr, K2, D2))[:, 1]
                             for cl, cr in zip(cl_all, cr_all)])
        label = "undistorted" if undistort else "raw pixels "
        print(f"   {label}: per pair median {statistics.median(per_pair):.2f} px "
              f"(pairs <= 0.5 px: {sum(p <= 0.5 for p in per_pair)}/{len(per_pair)}, worst "
              f"{max(per_pair):.1f} px); pooled matches of all pairs ({len(xl)}): median "
              f"{np.median(np.abs(dv)):.3f} px, 90th percentile {np.percentile(np.abs(dv), 90):.3f} px")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--study", action="store_true", help="also print the full study tables")
    ap.add_argument("--no-asift", action="store_true", help="leave ASIFT out of the spread table")
    args = ap.parse_args(argv)
    data = args.data
    if not data.is_dir():
        print(f"no data folder {data}: nothing to benchmark")
        return 1
    crot = croton()
    chess = (read_image(data / "opencv_stereo_calib_chessboard/left01.jpg"),
             read_image(data / "opencv_stereo_calib_chessboard/right01.jpg"))
    plants = (read_image(data / "middlebury_MiddEval3_testQ/Plants/im0.png"),
              read_image(data / "middlebury_MiddEval3_testQ/Plants/im1.png"))
    aloe = load_gt_scene(data, "Aloe")
    flower = load_gt_scene(data, "Flowerpots")
    citrus = rendered("citrus_branch")
    bench_speed({"croton": crot[:2], "chessboard01": chess, "Plants": plants})
    bench_spread({"Aloe": (*aloe[:2], "disp", aloe[2]), "Plants": (*plants, None, None),
                  "Flowerpots": (*flower[:2], "disp", flower[2]),
                  "croton": (*crot[:2], "pixels", crot[2]),
                  "citrus": (*citrus[:2], "pixels", citrus[2])}, asift=not args.no_asift)
    bench_correctness(data, crot)
    bench_hartley(data)
    if args.study:
        print("5. study tables")
        aloe_gt = aloe[2]
        for name, (left, right), gt in (("Aloe", aloe[:2], aloe_gt), ("Plants", plants, None),
                                        ("croton", crot[:2], None)):
            print(f"--- {name}")
            print(format_table(run_study(left, right, gt_disparity=gt)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
