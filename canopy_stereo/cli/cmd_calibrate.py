"""``canopy-stereo calibrate``: world-frame P matrices from 2D-3D points or chessboards."""
from __future__ import annotations

import numpy as np

from canopy_stereo.cli.common import parse_int_list
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.rig import Rig, save_rig

COMMAND = "calibrate"
HELP = "calibrate a stereo rig into a rig file (Gold Standard from 2D-3D points, or chessboards)"
DESCRIPTION = """Calibrate both cameras in one world frame and write a rig file.

--points PAIRS.csv: Gold Standard algorithm (normalised DLT + Levenberg-Marquardt)
from known 3D points (columns X,Y,Z,u_left,v_left,u_right,v_right; world unit = the
unit of X,Y,Z, set with --unit).
--chessboard LEFT_GLOB RIGHT_GLOB --pattern 9x6 --square 25: Zhang calibration with
lens distortion; world frame = left camera of the first pair (or --world-board I).

Prints the reprojection RMS and the per-axis triangulation error table (paper Table 1)."""


def add_arguments(p):
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--points", metavar="PAIRS.csv", help="2D-3D correspondences CSV")
    src.add_argument("--chessboard", nargs=2, metavar=("LEFT_GLOB", "RIGHT_GLOB"),
                     help="left and right chessboard images (quote the globs)")
    p.add_argument("--pattern", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    p.add_argument("--square", type=float, default=25.0, help="square size in world units (default 25)")
    p.add_argument("--world-board", type=int, default=None, metavar="I",
                   help="use the board of pair I as the world frame")
    p.add_argument("--unit", default="mm", help="world unit written to the rig file (default mm)")
    p.add_argument("--image-size", default=None, metavar="WxH",
                   help="image size for --points (default 640x480)")
    p.add_argument("-o", "--output", required=True, metavar="rig.yaml", help="rig file to write")
    p.add_argument("--plot", metavar="err.png", help="plot per-axis error against distance")


def run(args) -> int:
    if args.points:
        from canopy_stereo.geometry.calibration import calibrate_stereo_points, read_correspondences_csv

        X, xl, xr = read_correspondences_csv(args.points)
        cal = calibrate_stereo_points(X, xl, xr)
        w, h = parse_int_list(args.image_size, 2, "--image-size") if args.image_size else (640, 480)
        print(f"Gold Standard calibration from {len(X)} correspondences")
    else:
        from canopy_stereo.geometry.chessboard import calibrate_stereo_chessboard, expand_image_list
        from canopy_stereo.io.images import read_image

        pattern = tuple(parse_int_list(args.pattern, 2, "--pattern"))
        if args.square <= 0:
            raise CanopyStereoError("--square must be positive")
        from canopy_stereo.cli.progress import Progress

        bar = None

        def progress(total, name):
            nonlocal bar
            bar = bar or Progress(total, "finding the chessboard in pair")
            bar.step(name)

        try:
            cal = calibrate_stereo_chessboard(args.chessboard[0], args.chessboard[1], pattern, args.square,
                                              world_board=args.world_board, progress=progress)
        finally:
            if bar is not None:
                bar.close()
        first = read_image(expand_image_list(args.chessboard[0])[0], color=False)
        h, w = first.shape
        print(f"chessboard calibration, {len(cal.check.errors) // (pattern[0] * pattern[1])} pairs used; "
              f"stereo RMS {cal.rms_stereo:.3f} px")
    print(f"reprojection RMS: left {cal.rms_left:.3f} px, right {cal.rms_right:.3f} px")
    print(cal.check.table(args.unit))
    rig = Rig(P_left=cal.P_left, P_right=cal.P_right, image_size=(w, h), world_unit=args.unit,
              D_left=cal.D_left, D_right=cal.D_right)
    save_rig(rig, args.output, comment=f"canopy-stereo calibrate; baseline {rig.baseline:.2f} {args.unit}")
    print(f"wrote {args.output} (baseline {rig.baseline:.2f} {args.unit})")
    if args.plot:
        from canopy_stereo.geometry.chessboard import plot_triangulation_errors

        plot_triangulation_errors(cal.check, args.plot, args.unit)
        print(f"wrote {args.plot}")
    return 0 if np.all(np.isfinite(cal.check.mean_abs)) else 1
