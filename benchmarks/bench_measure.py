"""Accuracy and speed of leaf/canopy measurement and automatic plant masks.

Synthetic scenes with exact truth (canopy_stereo.sim) seen through the paper's rig:

* croton, the two marked leaves (97 x 160 and 86 x 145 mm, 600-720 mm away):
  length, width and area errors measured on the true cloud (measurement alone)
  and end to end on the reconstruction (reconstruct_pair + measure), over
  several seeds: mean and worst absolute error;
* croton canopy extents (height, width, depth) of the reconstruction against
  the true cloud, in the same ground frame (leaves cut by the image border left out);
* IoU of the automatic plant mask against the truth (leaves, stems, fruit) on
  croton (ExG + depth), seedling_tray (ExG) and citrus_branch (depth + colour learned from it);
* time of measure_scene on a reconstruction.

Run:  python benchmarks/bench_measure.py [--seeds 10] [--matcher sgbm]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.measure import measure_leaf, measure_scene
from canopy_stereo.pipeline.reconstruct import reconstruct_pair
from canopy_stereo.segmentation import auto_plant_mask
from canopy_stereo.sim import render_scene

#: SGBM settings that keep slanted leaves' depth slopes (see the report of issue 7).
TUNED_SGBM = {"block_size": 7, "p1": 8, "p2": 32}
PLANT_LABELS = (1, 2, 6)  # leaf, stem, fruit


def whole_plant_mask(labels: np.ndarray, leaf_ids: np.ndarray) -> np.ndarray:
    """Plant pixels (leaves, stems, fruit) without the leaves cut by the image border,
    whose true extent is unknown to any method."""
    plant = np.isin(labels, PLANT_LABELS)
    border = np.unique(np.concatenate([leaf_ids[0], leaf_ids[-1], leaf_ids[:, 0], leaf_ids[:, -1]]))
    return plant & ~np.isin(leaf_ids, border[border != 0])


def _rel(measured, truth):
    return 100.0 * (measured / truth - 1.0)


def _summary(name, errs):
    e = np.abs(np.asarray(errs))
    print(f"  {name:<34} mean |err| {e.mean(axis=0).round(2)}  worst {e.max(axis=0).round(2)}  (%)")


def croton(seeds: int, matcher: str, params: dict | None):
    true_err, rec_err, ext_err, times = [], [], [], []
    for seed in range(seeds):
        sim = render_scene("croton", seed=seed)
        P = sim.rig.P_left
        ids = sim.leaf_ids_left.astype(np.int64)
        plant = whole_plant_mask(sim.labels_left, ids)
        rec = reconstruct_pair(sim.left, sim.right, sim.rig, matcher=matcher, matcher_params=params)
        for lf in sim.truth["leaves"]:
            if not lf["marked"]:
                continue
            m = ids == lf["id"]
            t = measure_leaf(sim.xyz_left, m, leaf_id=lf["id"], camera=P)
            r = measure_leaf(rec.organized, m, leaf_id=lf["id"], camera=P)
            true_err.append([_rel(t.length, lf["length"]), _rel(t.width, lf["width"]), _rel(t.area, lf["area"])])
            rec_err.append([_rel(r.length, lf["length"]), _rel(r.width, lf["width"]), _rel(r.area, lf["area"])])
        truth = measure_scene(sim.xyz_left, leaf_ids=ids, mask=plant, camera=P)
        t0 = time.perf_counter()
        meas = measure_scene(rec.organized, leaf_ids=ids, mask=plant, camera=P,
                             ground=truth.report["frame"]["ground_plane"])
        times.append(time.perf_counter() - t0)
        ct, cm = truth.report["canopy"], meas.report["canopy"]
        ext_err.append([_rel(cm[k], ct[k]) for k in ("height", "width", "depth")])
        print(f"seed {seed}: leaves (L, W, A %) true {np.round(true_err[-2:], 2).tolist()} "
              f"reconstructed {np.round(rec_err[-2:], 2).tolist()}; extents (H, W, D %) "
              f"{np.round(ext_err[-1], 2).tolist()}", flush=True)
    print(f"croton, {seeds} seeds, marked leaves [length, width, area]:")
    _summary("true cloud (measurement alone)", true_err)
    _summary(f"reconstruction ({matcher} {params or 'defaults'})", rec_err)
    print("croton canopy extents [height, width, depth] of the reconstruction:")
    _summary("vs the true cloud, same frame", ext_err)
    print(f"  measure_scene on a reconstruction: {1e3 * np.mean(times):.0f} ms mean")


def masks(matcher: str, params: dict | None):
    print("automatic plant mask IoU (depth from the reconstruction):")
    for name, index, use_depth in (("croton", "exg", True), ("seedling_tray", "exg", False),
                                   ("citrus_branch", "none", True)):
        ious, times = [], []
        for seed in range(2):
            sim = render_scene(name, seed=seed)
            depth = None
            if use_depth:
                rec = reconstruct_pair(sim.left, sim.right, sim.rig, matcher=matcher, matcher_params=params)
                depth = np.linalg.norm(rec.organized - camera_centre(sim.rig.P_left), axis=-1)
            t0 = time.perf_counter()
            m = auto_plant_mask(sim.left, depth=depth, index=index) > 0
            times.append(time.perf_counter() - t0)
            truth = np.isin(sim.labels_left, PLANT_LABELS)
            ious.append((m & truth).sum() / (m | truth).sum())
        cues = ([f"index {index}"] if index != "none" else []) + (["depth"] if use_depth else [])
        if index == "none" and use_depth:
            cues.append("colour learned from the depth")
        print(f"  {name:<14} ({' + '.join(cues)}): IoU {', '.join(f'{v:.3f}' for v in ious)}  "
              f"({np.mean(times) * 1e3:.0f} ms per mask)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--matcher", default="sgbm")
    ap.add_argument("--default-params", action="store_true",
                    help="use the matcher's default parameters instead of the tuned SGBM ones")
    args = ap.parse_args()
    params = None if (args.default_params or args.matcher != "sgbm") else TUNED_SGBM
    croton(args.seeds, args.matcher, params)
    masks(args.matcher, params)


if __name__ == "__main__":
    main()
