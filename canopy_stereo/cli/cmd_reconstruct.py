"""``canopy-stereo reconstruct``: two images -> metric PLY point cloud."""
from __future__ import annotations

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
    p.add_argument("--disp-min", type=int, default=None, help="smallest disparity searched (px)")
    p.add_argument("--disp-max", type=int, default=None, help="largest disparity searched (px)")
    p.add_argument("--organized", metavar="ORG.npy",
                   help="also save the H x W x 3 world points of the left image's pixels (NaN where none)")
    p.add_argument("--disparity-out", metavar="DISP.pfm", help="also save the rectified disparity")
    m = p.add_argument_group("measurement (see also: canopy-stereo measure)")
    m.add_argument("--measure", action="store_true", help="measure leaves and canopy after reconstructing")
    m.add_argument("--leaf-ids", metavar="IDS.png", help="leaf-id image on the left image (0 = none)")
    m.add_argument("--report", metavar="REPORT.json", help="measurement report (required with --measure)")
    m.add_argument("--csv", metavar="LEAVES.csv", help="per-leaf table")
    m.add_argument("--plot", metavar="VIEWS.png", help="top and side views with the measured dimensions")


def run(args) -> int:
    from canopy_stereo.errors import CanopyStereoError

    if args.measure and not args.report:
        raise CanopyStereoError("--measure needs --report REPORT.json")
    if (args.leaf_ids or args.report or args.csv or args.plot) and not args.measure:
        raise CanopyStereoError("--leaf-ids/--report/--csv/--plot need --measure")
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

        rect = rectify_rig(rig, args.method, left, right, match_pairs=load_match_pairs(args.match_pairs))
    rec = reconstruct_pair(left, right, rig, method=args.method, matcher=args.matcher, mask=mask,
                           disp_min=args.disp_min, disp_max=args.disp_max, rectification=rect)
    t = time.perf_counter()
    # PLYs are millimetres whatever the rig's unit (canopy_stereo.io.ply.PLY_UNIT)
    write_ply(args.output, rec.points * (rig.metres_per_unit * 1000.0), rec.colors, unit="mm",
              comments=[f"canopy-stereo reconstruct method={rec.rectification.method} matcher={args.matcher}"])
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
    if args.measure:
        t = time.perf_counter()
        _measure(args, rec, rig, mask)
        rec.timings["measure"] = time.perf_counter() - t
    lo, hi = rec.bounding_box()
    u = rig.world_unit
    print(f"points: {len(rec.points)}  (disparity range searched {rec.disp_range[0]}..{rec.disp_range[1]} px)")
    print(f"bounding box ({u}): x {lo[0]:.1f}..{hi[0]:.1f}  y {lo[1]:.1f}..{hi[1]:.1f}  z {lo[2]:.1f}..{hi[2]:.1f}")
    print("time per stage: " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in rec.timings.items())
          + f"; total {(time.perf_counter() - t0) * 1e3:.0f} ms")
    print(f"wrote {args.output} (millimetres)")
    return 0


def _measure(args, rec, rig, mask) -> None:
    """Measure the reconstruction's leaves and canopy; write REPORT.json (+ CSV, PNG)."""
    from canopy_stereo.measure import measure_scene, plot_views, write_report
    from canopy_stereo.segmentation import read_leaf_ids

    ids = read_leaf_ids(args.leaf_ids) if args.leaf_ids else None
    res = measure_scene(rec.organized, leaf_ids=ids, mask=mask, ground="auto", unit=rig.world_unit,
                        camera=rig.P_left)
    write_report(res.report, args.report, csv=args.csv)
    if args.plot:
        plot_views(res, args.plot)
    c, u = res.report["canopy"], rig.world_unit
    print(f"canopy: height {c['height']:.1f} {u}, width {c['width']:.1f} {u}, depth {c['depth']:.1f} {u}, "
          f"hull volume {c['hull_volume'] / 1e6 if u == 'mm' else c['hull_volume']:.3g} "
          f"{'L' if u == 'mm' else u + '^3'}; {len(res.report['leaves'])} leaves measured")
    for lf in res.report["leaves"]:
        print(f"  leaf {lf['id']}: length {lf['length']:.1f} {u}, width {lf['width']:.1f} {u}, "
              f"area {lf['area']:.0f} {u}^2")
    print(f"wrote {args.report}" + (f", {args.csv}" if args.csv else "") + (f", {args.plot}" if args.plot else ""))
