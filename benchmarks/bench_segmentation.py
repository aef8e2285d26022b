"""Plants, not green things: the automatic plant mask against the current seeder.

Per simulated scene (exact truth, canopy_stereo.sim; depth cue: the cloud that
reconstruct_pair makes with ELAS from the rendered 640 x 480 pair):

* mask IoU against the truth plant pixels (leaves, stems, fruit);
* distractor pixels taken: the fraction of the pots', soil's and objects' pixels
  (a green watering can, a green box, a green stake) in the mask;
* plants found and, per plant, the height error (%) of measure_plants on the exact
  cloud with the mask's instances (height above the pot rim / soil; the seeder's
  mask is split into instances the same way);
* time per frame of the mask (ms, wall) and its CPU time (ms, process_time: all threads).

Then the real Middlebury 2014 Plants pair (../shared/data, if present): the share
of each hand-checked region (test/data/plants_regions.json) the mask takes, with
the ELAS disparity as depth cue, as ``segment --auto`` does, and ("cloud") the mask
``reconstruct --auto-mask`` uses (the pair's cloud through the bundled rig).

"seeder" is the current default of the one seeder (segmentation.auto: ExG +
depth + GrabCut, IMAGE_SEEDER) with the distance map of the same cloud; "plants"
is segment_plants. Run:  python benchmarks/bench_segmentation.py [--seeds 2]

``--video``: instead, segment_node's own work (MaskPropagator with VIDEO_SEEDER and the
node's max_pixels) on bench_graph.py's 640x480 frames (Plants drifting, croton; Aloe with
../shared/data): CPU ms per frame (one OpenCV thread; full cuts and propagated frames
apart), and the propagated frames' graph cut against OpenCV's own
``cv2.grabCut(..., GC_EVAL_FREEZE_MODEL)`` of the same seed (CPU per call, pixels that differ).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.measure import measure_plants
from canopy_stereo.pipeline.reconstruct import reconstruct_pair
from canopy_stereo.segmentation import IMAGE_SEEDER, plant_instances, plant_mask, segment_plants
from canopy_stereo.sim import render_scene
from canopy_stereo.sim.primitives import DISTRACTOR_LABELS, PLANT_LABELS

REPO = Path(__file__).resolve().parents[1]


def _timed(fn):
    """``(fn(), "wall ms / CPU ms")``."""
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, f"{1000.0 * (time.perf_counter() - t):6.0f} ms wall {1000.0 * (time.process_time() - c):6.0f} ms CPU"


def _height_errors(sim, instances, ground):
    """Height errors (%) against the truth plant each instance shows most: ``(of the plants
    wholly in view, of those the image border cuts)``."""
    if not instances.any():
        return [], []
    res = measure_plants(sim.xyz_left, instances, camera=sim.rig.P_left, ground=ground, separate=False)
    errs: tuple[list, list] = ([], [])
    for rep in res["plants"]:
        ids, counts = np.unique(sim.plants_left[instances == rep["plant_index"]], return_counts=True)
        k = int(ids[np.argmax(counts)])
        if k == 0 or "canopy" not in rep:
            continue
        truth = sim.truth["plants"][k - 1]["height"]
        errs[bool(rep["at_image_border"])].append(100.0 * (rep["canopy"]["height"] / truth - 1.0))
    return errs


def simulated(name: str, seed: int) -> None:
    sim = render_scene(name, seed=seed)
    rec = reconstruct_pair(sim.left, sim.right, sim.rig)
    P = sim.rig.P_left
    dist = np.linalg.norm(rec.organized - camera_centre(P), axis=-1)
    truth = np.isin(sim.labels_left, PLANT_LABELS)
    distractor = np.isin(sim.labels_left, DISTRACTOR_LABELS)
    in_view = int(np.count_nonzero(np.bincount(sim.plants_left.ravel())[1:] >= 50))
    ground = "view" if name == "seedling_tray" else "auto"
    old, old_ms = _timed(lambda: plant_mask(sim.left, IMAGE_SEEDER, depth=dist) > 0)
    new, new_ms = _timed(lambda: segment_plants(sim.left, points=rec.organized, camera=P))
    old_inst, _ = plant_instances(old, 1.0 / np.where(np.isfinite(dist), dist, np.nan))
    for label, mask, inst, ms in (("seeder", old, old_inst, old_ms),
                                  ("plants", new.mask > 0, new.instances, new_ms)):
        iou = (mask & truth).sum() / max(1, (mask | truth).sum())
        taken = (mask & distractor).sum() / max(1, distractor.sum())
        errs, cut = _height_errors(sim, inst, ground)
        worst = f"{max(abs(e) for e in errs):6.2f}" if errs else "   n/a"
        border = f" (+{len(cut)} cut by the border: worst {max(abs(e) for e in cut):.1f} %)" if cut else ""
        print(f"  {name:<19}{seed:>2}  {label:<7} IoU {iou:5.3f}  distractors taken {100 * taken:5.1f} %  "
              f"plants {int(inst.max()):>2}/{in_view:<2}  height |err| worst {worst} %  "
              f"median {np.median(np.abs(errs)) if errs else float('nan'):5.2f} %{border}  {ms}")


def real_plants(shared: Path) -> None:
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.io.images import read_image

    folder = shared / "middlebury_MiddEval3_testQ" / "Plants"
    left, right = read_image(folder / "im0.png"), read_image(folder / "im1.png")
    grey = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    d = compute_disparity(grey, cv2.cvtColor(right, cv2.COLOR_BGR2GRAY), matcher="elas", disp_min=0, disp_max=80)
    fx = json.loads((REPO / "test" / "data" / "plants_regions.json").read_text())
    regions = {}
    for r in fx["regions"]:
        m = np.zeros(grey.shape, np.uint8)
        for poly in r["polygons"]:
            cv2.fillPoly(m, [np.array(poly, np.int32)], 1)
        regions[r["name"]] = m.astype(bool) & ((grey <= fx["wall_grey"]) if r["kind"] == "foliage" else True)
    old, old_ms = _timed(lambda: plant_mask(left, IMAGE_SEEDER, disparity=d) > 0)
    new, new_ms = _timed(lambda: segment_plants(left, disparity=d))
    # the mask reconstruct --auto-mask (and --measure, batch, demo) uses: the cloud of the pair
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.measure.plant import camera_mm_of, plant_mask_of

    rig = load_rig(REPO / "config" / "plants_rig.yaml")
    rec = reconstruct_pair(left, right, rig)
    cloud, cloud_ms = _timed(lambda: plant_mask_of(left, rec.organized * 1000.0 * rig.metres_per_unit,
                                                   camera_mm=camera_mm_of(rig)))
    for label, seg, ms in (("seeder", None, old_ms), ("plants", new, new_ms), ("cloud", cloud, cloud_ms)):
        mask = old if seg is None else seg.mask > 0
        cov = "  ".join(f"{k} {100 * (mask & m).sum() / m.sum():5.1f} %" for k, m in regions.items())
        found = "" if seg is None else f"  plants {seg.n_plants}"
        print(f"  Plants 710x496  {label:<7} {cov}{found}  {ms}")


def video(scenes, n_frames: int) -> None:
    """CPU per frame of segment_node's segmentation (see the module docstring)."""
    import sys

    sys.path.insert(0, str(REPO))
    from benchmarks.bench_graph import bench_frames
    from canopy_stereo.segmentation.auto import VIDEO_SEEDER, seed_labels
    from canopy_stereo.segmentation.colour_model import grabcut_with_models
    from canopy_stereo.segmentation.propagate import DEFAULT_MAX_PIXELS, MaskPropagator

    cv2.setNumThreads(1)
    print(f"segment_node's segmentation, {n_frames} frames of 640x480, CPU ms (one OpenCV thread)")
    for scene in scenes:
        _, frames = bench_frames(scene, "640x480", n_frames=n_frames)
        MaskPropagator(settings=VIDEO_SEEDER, max_pixels=DEFAULT_MAX_PIXELS).segment(frames[0][0])  # warm-up
        prop = MaskPropagator(settings=VIDEO_SEEDER, max_pixels=DEFAULT_MAX_PIXELS)
        full, propagated = [], []
        for left, _ in frames:
            cuts = prop.full_cuts
            t0 = time.process_time()
            prop.segment(left)
            (full if prop.full_cuts > cuts else propagated).append(1e3 * (time.process_time() - t0))
        ours = opencv = 0.0
        differ = undecided = 0
        for left, _ in frames:
            small = cv2.resize(left, (160, 120), interpolation=cv2.INTER_AREA)
            seed = seed_labels(small, VIDEO_SEEDER.replace(scale=1.0))
            t0 = time.process_time()
            a = grabcut_with_models(small, seed, *prop._models)
            ours += time.process_time() - t0
            b = seed.copy()
            t0 = time.process_time()
            cv2.grabCut(small, b, None, prop._models[1].grabcut_model(), prop._models[0].grabcut_model(), 1,
                        cv2.GC_EVAL_FREEZE_MODEL)
            opencv += time.process_time() - t0
            differ += int((a != b).sum())
            undecided += int((seed >= 2).sum())
        n = len(frames)
        print(f"  {scene:<7} {np.mean(full + propagated):5.2f} ms/frame ({len(full)} full cuts "
              f"{np.mean(full):5.1f} ms, {len(propagated)} propagated {np.mean(propagated):4.2f} ms); "
              f"propagated cut {1e3 * ours / n:4.2f} ms vs cv2.grabCut {1e3 * opencv / n:4.2f} ms, "
              f"{differ} of {undecided} undecided pixels differ")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=2, help="seeds per distractor scene (default 2)")
    ap.add_argument("--video", action="store_true", help="segment_node's CPU per frame instead (see above)")
    ap.add_argument("--frames", type=int, default=60, help="--video: frames per scene (default 60)")
    args = ap.parse_args()
    if args.video:
        shared = REPO.parent / "shared" / "data"
        video(["plants", "croton"] + (["aloe"] if shared.is_dir() else []), args.frames)
        return
    segment_plants(np.zeros((32, 32, 3), np.uint8), disparity=np.ones((32, 32)))  # warm-up (imports)
    print("simulated scenes, 640x480, depth from reconstruct_pair (ELAS); heights on the exact cloud")
    for name in ("potted_distractors", "pots_side_by_side"):
        for seed in range(args.seeds):
            simulated(name, seed)
    simulated("seedling_tray", 0)
    shared = REPO.parent / "shared" / "data"
    if shared.is_dir():
        print("real pair: share of each hand-checked region taken (foliage: want >= 85 %; can <= 5 %, pots <= 10 %)")
        real_plants(shared)


if __name__ == "__main__":
    main()
