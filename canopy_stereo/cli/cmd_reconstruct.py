"""``canopy-stereo reconstruct``: two images -> metric PLY point cloud."""
from __future__ import annotations

import sys
import time

import numpy as np

from canopy_stereo.cli.common import add_rig_argument
from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names, matcher_spec
from canopy_stereo.io.images import read_image
from canopy_stereo.io.ply import write_ply
from canopy_stereo.io.rig import load_rig
from canopy_stereo.pipeline.reconstruct import RECTIFICATION_METHODS, reconstruct_pair

COMMAND = "reconstruct"
HELP = "reconstruct a stereo pair into a metric point cloud (PLY, millimetres)"
DESCRIPTION = """Rectify, match densely, map the matches back to the original images and
triangulate them with the rig's world-frame P matrices. Writes a binary PLY in the rig's
world frame, in millimetres whatever the rig's unit (as every PLY of the package; the header
says so), and prints the number of points, the bounding box and the time per stage."""


def add_arguments(p):
    p.add_argument("left", help="left image (raw, as captured)")
    p.add_argument("right", help="right image")
    add_rig_argument(p)
    p.add_argument("-o", "--output", required=True, metavar="cloud.ply")
    p.add_argument("--method", choices=RECTIFICATION_METHODS, default=None,
                   help="rectification: fusiello or hartley (the rig's homographies when it has them, "
                        "else from matches); default: the rig's method, else fusiello")
    p.add_argument("--match-pairs", nargs=2, metavar=("LEFT_GLOB", "RIGHT_GLOB"),
                   help="hartley: pool matches from more pairs taken by the same rig")
    p.add_argument("--matcher", choices=matcher_names(), default=DEFAULT_MATCHER,
                   help=f"dense matcher (default {DEFAULT_MATCHER}, as in the paper)")
    p.add_argument("--mask", metavar="MASK.png", help="foreground mask on the left image (non-zero = keep)")
    p.add_argument("--near", type=float, default=None, metavar="M",
                   help="working distance: nearest depth searched, metres along the optical axis (rig key "
                        "near_m; default: the rig's disp_min/disp_max, near_m/far_m, else 8 baselines)")
    p.add_argument("--far", type=float, default=None, metavar="M",
                   help="working distance: farthest depth searched, metres (rig key far_m; default infinity)")
    p.add_argument("--disp-min", type=int, default=None, help="smallest disparity searched (px; overrides --far)")
    p.add_argument("--disp-max", type=int, default=None, help="largest disparity searched (px; overrides --near)")
    p.add_argument("--organized", metavar="ORG.npy",
                   help="also save the H x W x 3 world points of the left image's pixels (NaN where none)")
    p.add_argument("--disparity-out", metavar="DISP.pfm", help="also save the rectified disparity")
    p.add_argument("--auto-mask", action="store_true",
                   help="keep only the plant found by the automatic plant mask (colour and depth) in the "
                        "cloud; with --measure it is the default when no --mask is given")
    p.add_argument("--whole-scene", action="store_true",
                   help="measure every point (no plant mask; the walls and table count as canopy)")
    m = p.add_argument_group("measurement (see also: canopy-stereo measure)")
    m.add_argument("--measure", action="store_true",
                   help="measure leaves and canopy after reconstructing (the package's one measuring "
                        "pipeline: the same numbers as demo, batch and view)")
    m.add_argument("--voxel-size", type=float, default=None, metavar="MM",
                   help="voxel edge of the occupancy volume, millimetres (default 10)")
    m.add_argument("--leaf-ids", metavar="IDS.png", help="leaf-id image on the left image (0 = none)")
    m.add_argument("--report", metavar="REPORT.json", help="measurement report (required with --measure)")
    m.add_argument("--csv", metavar="LEAVES.csv", help="per-leaf table")
    m.add_argument("--plot", metavar="VIEWS.png", help="top and side views with the measured dimensions")


def run(args) -> int:
    from canopy_stereo.errors import CanopyStereoError

    if args.measure and not args.report:
        raise CanopyStereoError("--measure needs --report REPORT.json")
    if (args.leaf_ids or args.report or args.csv or args.plot or args.voxel_size is not None) and not args.measure:
        raise CanopyStereoError("--leaf-ids/--report/--csv/--plot/--voxel-size need --measure")
    if sum(map(bool, (args.mask, args.auto_mask, args.whole_scene))) > 1:
        raise CanopyStereoError("--mask, --auto-mask and --whole-scene exclude each other: choose one")
    rig = load_rig(args.rig)  # inputs first: a bad file fails at once, in one line
    left, right = read_image(args.left), read_image(args.right)
    mask = read_image(args.mask, color=False) if args.mask else None
    if matcher_spec(args.matcher).compiled:
        from canopy_stereo.cli.progress import warm_up_kernels

        warm_up_kernels()  # says so when numba compiles (first run); not in the stage times
    t0 = time.perf_counter()
    rect = None
    if args.match_pairs:
        from canopy_stereo.cli.cmd_rectify import load_match_pairs
        from canopy_stereo.pipeline.reconstruct import rectify_rig

        rect = rectify_rig(rig, args.method, left=left, right=right,
                           match_pairs=load_match_pairs(args.match_pairs))
    rec = reconstruct_pair(left, right, rig, method=args.method, matcher=args.matcher, mask=mask,
                           disp_min=args.disp_min, disp_max=args.disp_max, near_m=args.near, far_m=args.far,
                           rectification=rect)
    for warning in rec.warnings:
        print(f"warning: {warning}", file=sys.stderr, flush=True)
    written = []
    measured = None
    if args.measure or args.auto_mask:
        t = time.perf_counter()
        measured = _measure(args, rec, rig, left, mask, written)
        rec.timings["measure" if args.measure else "plant mask"] = time.perf_counter() - t
    t = time.perf_counter()
    points, colors = rec.points, rec.colors
    kept = "whole scene"
    if args.auto_mask:
        points, colors = _plant_points(rec, measured.mask)
        kept = "automatic plant mask"
    # PLYs are millimetres whatever the rig's unit (canopy_stereo.io.ply.PLY_UNIT)
    write_ply(args.output, points * (rig.metres_per_unit * 1000.0), colors=colors, unit="mm",
              comments=[f"canopy-stereo reconstruct method={rec.rectification.method} matcher={args.matcher} "
                        f"points={'given mask' if mask is not None else kept}"])
    if args.organized:
        from pathlib import Path

        Path(args.organized).parent.mkdir(parents=True, exist_ok=True)
        np.save(args.organized, rec.organized.astype(np.float32))
    if args.disparity_out:
        from canopy_stereo.io.pfm import write_pfm

        d = rec.disparity.copy()
        d[d < 0] = np.inf
        write_pfm(args.disparity_out, d)
    rec.timings["write"] = time.perf_counter() - t
    lo, hi = rec.bounding_box()
    u = rig.world_unit
    print(f"points: {len(points)}  (disparity range searched {rec.disp_range[0]}..{rec.disp_range[1]} px)")
    print(f"bounding box ({u}): x {lo[0]:.1f}..{hi[0]:.1f}  y {lo[1]:.1f}..{hi[1]:.1f}  z {lo[2]:.1f}..{hi[2]:.1f}")
    print("time per stage: " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in rec.timings.items())
          + f"; total {(time.perf_counter() - t0) * 1e3:.0f} ms")
    print(f"wrote {args.output} (millimetres" + (", plant only)" if kept != "whole scene" else ")")
          + "".join(f", {p}" for p in written))
    return 0


def _plant_points(rec, plant):
    """Points and colours of the reconstruction's pixels on the plant mask (original grid)."""
    keep = plant[rec.pixels[:, 1], rec.pixels[:, 0]]
    return rec.points[keep], rec.colors[keep]


def _measure(args, rec, rig, left, mask, written: list):
    """Measure the reconstruction with the package's one pipeline (or only find the plant
    mask, for --auto-mask without --measure); print the summary; write REPORT.json, CSV,
    PNG and the mask overlay next to the cloud. Returns the
    :class:`~canopy_stereo.measure.plant.PlantMeasurement` (None for the whole scene
    without --measure)."""
    from pathlib import Path

    from canopy_stereo.measure.plant import (
        DEFAULT_VOXEL_SIZE_MM,
        PlantMeasurement,
        automatic_plant_mask,
        measure_plant,
        measurement_lines,
        write_overlay,
    )

    overlay = Path(args.output).with_name(Path(args.output).stem + "_overlay.png")
    if not args.measure:
        plant = automatic_plant_mask(left, rec.organized, rig)
        found = PlantMeasurement(report={}, scene=None, mask=plant, mask_source="automatic",
                                 organized_mm=rec.organized)
        written.append(write_overlay(overlay, found, left))
        print(f"plant: automatic plant mask, {plant.mean() * 100:.1f} % of the left image")
        return found
    if mask is None and not args.whole_scene and not args.auto_mask:
        print("no --mask given: measuring the plant found by the automatic plant mask "
              "(--whole-scene measures every point)")
    ids = None
    if args.leaf_ids:
        from canopy_stereo.segmentation import read_leaf_ids

        ids = read_leaf_ids(args.leaf_ids)
    res = measure_plant(left, rec.disparity, rig, rectification=rec.rectification, mask=mask, leaf_ids=ids,
                        whole_scene=args.whole_scene,
                        voxel_size_mm=DEFAULT_VOXEL_SIZE_MM if args.voxel_size is None else args.voxel_size)
    from canopy_stereo.measure import plot_views, write_report

    write_report(res.report, args.report, csv=args.csv)
    written.append(args.report)
    if args.csv:
        written.append(args.csv)
    if args.plot:
        plot_views(res.scene, args.plot)
        written.append(args.plot)
    if not args.whole_scene:
        written.append(write_overlay(overlay, res, left))
    for line in measurement_lines(res.report, max_leaves=len(res.report["leaves"])):
        print(line)
    return res
