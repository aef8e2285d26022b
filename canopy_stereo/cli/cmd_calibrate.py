"""``canopy-stereo calibrate``: world-frame P matrices from 2D-3D points or chessboards."""
from __future__ import annotations

import numpy as np

from canopy_stereo.cli.common import check_at_least, check_positive, check_world_unit, parse_int_list
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.rig import Rig, save_rig

COMMAND = "calibrate"
HELP = ("calibrate a stereo rig into a rig file (Gold Standard from 2D-3D points, or chessboards), "
        "or import another tool's calibration (--from)")
DESCRIPTION = """Calibrate both cameras in one world frame and write a rig file.

--points PAIRS.csv: Gold Standard algorithm (normalised DLT + Levenberg-Marquardt)
from known 3D points (columns X,Y,Z,u_left,v_left,u_right,v_right; world unit = the
unit of X,Y,Z, set with --unit).
--chessboard LEFT_GLOB RIGHT_GLOB --pattern 9x6 --square 25: Zhang calibration with
lens distortion; world frame = left camera of the first pair (or --world-board I).

--world-rig PLACEMENTS.yaml LEFT_GLOB RIGHT_GLOB --pattern 7x5 --square 50: the paper's
world-rig calibration: a chessboard photographed at known places (PLACEMENTS.yaml, one
placement per image pair in the sorted order of the globs); corners detected with
sub-pixel refinement, their order resolved from the geometry (symmetric boards, reversed
detections), Gold Standard P matrices in the placements' world frame; pairs without the
board are listed and skipped; Table 1 is leave-one-placement-out.
--from FORMAT FILES...: import a calibration another tool wrote: ros-yaml (camera_calibration's
left.yaml right.yaml), ros-ini (its ost.txt, or left.ini right.ini), kalibr (camchain.yaml,
pinhole radtan/equidistant), opencv (stereoCalibrate FileStorage YAML/XML: M1 D1 M2 D2 R T
[R1 R2 P1 P2], one or two files; --image-size when they hold none), middlebury (calib.txt).
World frame = the left camera's optical frame; unit = the file's (ROS, Kalibr: m;
Middlebury: mm; OpenCV: --unit, default mm); the lens distortion is kept.
--paper-layout -o placements.yaml: write the placements of the paper's layout (three lines
at -10, 0, +10 degrees, 15 marks each, 7x5 board of 50 mm squares; see --first-mark ...).

Prints the reprojection RMS and the per-axis triangulation error table (paper Table 1)."""


def add_arguments(p):
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--points", metavar="PAIRS.csv", help="2D-3D correspondences CSV")
    src.add_argument("--chessboard", nargs=2, metavar=("LEFT_GLOB", "RIGHT_GLOB"),
                     help="left and right chessboard images (quote the globs)")
    src.add_argument("--world-rig", nargs=3, metavar=("PLACEMENTS.yaml", "LEFT_GLOB", "RIGHT_GLOB"),
                     help="world-rig calibration (paper sec. 2.1): board placements and the left and "
                          "right images (quote the globs)")
    src.add_argument("--from", dest="from_files", nargs="+", metavar="FORMAT FILES",
                     help="import a calibration: FORMAT (ros-yaml, ros-ini, kalibr, opencv, middlebury) "
                          "then its file(s)")
    src.add_argument("--paper-layout", action="store_true",
                     help="write the placements of the paper's calibration layout to -o and exit")
    lay = p.add_argument_group("--paper-layout options (millimetres)")
    lay.add_argument("--first-mark", type=float, default=None, metavar="MM",
                     help="distance of the first mark on each line from the origin (default 1000)")
    lay.add_argument("--mark-spacing", type=float, default=None, metavar="MM",
                     help="spacing of the marks along a line (default 50)")
    lay.add_argument("--marks-per-line", type=int, default=None, metavar="N", help="default 15")
    lay.add_argument("--line-angles", default=None, metavar="A,B,C",
                     help="angles of the lines about the origin, degrees (default: --line-angles=-10,0,10)")
    lay.add_argument("--corner-height", type=float, default=None, metavar="MM",
                     help="height of the board's lowest corner row above the sheet (default 75)")
    wr = p.add_argument_group("--world-rig options")
    wr.add_argument("--max-rms", type=float, default=3.0, metavar="PX",
                    help="reprojection RMS above which a pair contradicts its placement (default 3)")
    wr.add_argument("--no-loo", action="store_true",
                    help="Table 1 from the rig fitted on all pairs instead of leave-one-placement-out")
    p.add_argument("--pattern", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    p.add_argument("--square", type=float, default=25.0, help="square size in world units (default 25)")
    p.add_argument("--world-board", type=int, default=None, metavar="I",
                   help="use the board of pair I as the world frame")
    p.add_argument("--unit", default=None, help="world unit written to the rig file (default mm; with "
                   "--from: the unit of the file's translations, default the format's)")
    p.add_argument("--image-size", default=None, metavar="WxH",
                   help="image size for --points (default 640x480)")
    p.add_argument("-o", "--output", required=True, metavar="rig.yaml", help="rig file to write")
    p.add_argument("--plot", metavar="err.png", help="plot per-axis error against distance")
    # --world-rig takes the board from the placements and --paper-layout defaults to the
    # paper's 7x5 board of 50 mm squares: None = not given (--chessboard: 9x6, 25)
    p.set_defaults(pattern=None, square=None)


def _check_arguments(args) -> None:
    """Every option checked before any file is read (one line, exit 2 when wrong)."""
    check_world_unit(args.unit)
    check_positive(args.square, "--square")
    if args.image_size:
        for v in parse_int_list(args.image_size, 2, "--image-size"):
            check_at_least(v, 1, "each of --image-size")
    if args.chessboard:
        for v in parse_int_list(args.pattern, 2, "--pattern"):
            check_at_least(v, 2, "each inner-corner count of --pattern")
        if args.world_board is not None:
            check_at_least(args.world_board, 0, "--world-board")
    elif args.world_board is not None:
        raise CanopyStereoError("--world-board needs --chessboard")


def run(args) -> int:
    if args.from_files:
        return _run_import(args)
    args.unit = args.unit or "mm"
    if args.paper_layout:
        return _run_paper_layout(args)
    if args.world_rig:
        return _run_world_rig(args)
    if args.pattern is None:
        args.pattern = "9x6"
    if args.square is None:
        args.square = 25.0
    _check_arguments(args)
    if args.points:
        from canopy_stereo.geometry.calibration import calibrate_stereo_points
        from canopy_stereo.io.correspondences import read_correspondences_csv

        X, xl, xr = read_correspondences_csv(args.points)
        cal = calibrate_stereo_points(X, xl, xr)
        w, h = parse_int_list(args.image_size, 2, "--image-size") if args.image_size else (640, 480)
        print(f"Gold Standard calibration from {len(X)} correspondences")
    else:
        from canopy_stereo.geometry.chessboard import calibrate_stereo_chessboard
        from canopy_stereo.io.images import ImageFiles

        pattern = tuple(parse_int_list(args.pattern, 2, "--pattern"))
        from canopy_stereo.progress import Progress

        bar = None

        def progress(total, name):
            nonlocal bar
            bar = bar or Progress(total, "finding the chessboard in pair")
            bar.step(name)

        lefts = ImageFiles(args.chessboard[0], color=False, what="left chessboard images")
        rights = ImageFiles(args.chessboard[1], color=False, what="right chessboard images")
        try:
            cal = calibrate_stereo_chessboard(lefts, rights, pattern=pattern, square_size=args.square,
                                              world_board=args.world_board, progress=progress)
        finally:
            if bar is not None:
                bar.close()
        h, w = lefts[0].shape[:2]
        print(f"chessboard calibration, {len(cal.check.errors) // (pattern[0] * pattern[1])} pairs used; "
              f"stereo RMS {cal.rms_stereo:.3f} px")
    print(f"reprojection RMS: left {cal.rms_left:.3f} px, right {cal.rms_right:.3f} px")
    print(cal.check.table(args.unit))
    rig = Rig(P_left=cal.P_left, P_right=cal.P_right, image_size=(w, h), world_unit=args.unit,
              D_left=cal.D_left, D_right=cal.D_right)
    rig = _with_working_distance(rig, cal.check)
    save_rig(rig, args.output, comment=f"canopy-stereo calibrate; baseline {rig.baseline:.2f} {args.unit}; "
                                       f"working distance {_working_distance_text(rig)} (seen, with margin)")
    print(f"wrote {args.output} (baseline {rig.baseline:.2f} {args.unit}; working distance "
          f"{_working_distance_text(rig)}, the disparity range searched)")
    if args.plot:
        from canopy_stereo.geometry.chessboard import plot_triangulation_errors

        plot_triangulation_errors(cal.check, args.plot, unit=args.unit)
        print(f"wrote {args.plot}")
    return 0 if np.all(np.isfinite(cal.check.mean_abs)) else 1


def _run_paper_layout(args) -> int:
    """``--paper-layout -o placements.yaml``: the paper's layout as a placements file."""
    from canopy_stereo.geometry.board_placements import PAPER_LAYOUT, paper_layout_placements
    from canopy_stereo.io.placements import write_placements

    layout = {}
    if args.first_mark is not None:
        layout["first_mark"] = args.first_mark
    if args.mark_spacing is not None:
        layout["mark_spacing"] = args.mark_spacing
    if args.marks_per_line is not None:
        layout["marks_per_line"] = args.marks_per_line
    if args.corner_height is not None:
        layout["lowest_corner_height"] = args.corner_height
    if args.line_angles is not None:
        try:
            layout["angles_deg"] = tuple(float(a) for a in args.line_angles.split(",") if a.strip())
        except ValueError:
            raise CanopyStereoError(f"--line-angles must be numbers separated by commas, got "
                                    f"{args.line_angles!r}") from None
        if not layout["angles_deg"]:
            raise CanopyStereoError("--line-angles needs at least one angle")
    pattern = tuple(parse_int_list(args.pattern, 2, "--pattern")) if args.pattern else (7, 5)
    square = 50.0 if args.square is None else float(args.square)
    placements = paper_layout_placements(pattern=pattern, square=square, **layout)
    full = {**PAPER_LAYOUT, **layout}
    angles = ", ".join(f"{a:+g}" for a in full["angles_deg"])
    write_placements(placements, args.output, comment=(
        "The paper's world-rig calibration layout (Ni & Burks sec. 2.1), written by\n"
        "canopy-stereo calibrate --paper-layout. World frame: the floor sheet is y = 0 (x across,\n"
        "y down, z away from the cameras along the middle line), unit mm. Lines through the\n"
        f"origin at {angles} degrees; {full['marks_per_line']} marks per line every "
        f"{full['mark_spacing']:g} mm from {full['first_mark']:g} mm;\n"
        "the board stands vertically on each mark, centred on it and facing the origin, its lowest\n"
        f"corner row {full['lowest_corner_height']:g} mm above the sheet. Photograph pair k with "
        "the board at placement k."))
    print(f"wrote {args.output}: {len(placements)} placements of a {pattern[0]}x{pattern[1]} board "
          f"({square:g} mm squares) on lines at {angles} degrees")
    return 0


def _run_world_rig(args) -> int:
    """``--world-rig PLACEMENTS.yaml LEFT_GLOB RIGHT_GLOB``: the paper's world-rig calibration."""
    from canopy_stereo.geometry.board_placements import parse_pattern
    from canopy_stereo.geometry.world_rig import calibrate_world_rig, plot_world_rig_errors
    from canopy_stereo.io.placements import load_placements

    placements_path, left_glob, right_glob = args.world_rig
    placements = load_placements(placements_path)
    pattern = parse_pattern(args.pattern, "--pattern") if args.pattern else placements.pattern
    if pattern != placements.pattern:
        raise CanopyStereoError(f"--pattern {pattern[0]}x{pattern[1]} but {placements_path} says "
                                f"{placements.pattern[0]}x{placements.pattern[1]}")
    if args.square is not None and not (args.square > 0):
        raise CanopyStereoError("--square must be positive")
    if args.square is not None and abs(args.square - placements.square) > 1e-9 * max(1.0, args.square):
        raise CanopyStereoError(f"--square {args.square:g} but {placements_path} says {placements.square:g}")
    if not args.max_rms > 0:
        raise CanopyStereoError("--max-rms must be positive")
    if args.unit != "mm" and args.unit != placements.unit:
        raise CanopyStereoError(f"--unit {args.unit} but {placements_path} says {placements.unit}")

    def progress(msg):
        print(msg, flush=True)

    from canopy_stereo.io.images import ImageFiles

    lefts = ImageFiles(left_glob, color=False, what="left images")
    rights = ImageFiles(right_glob, color=False, what="right images")
    cal = calibrate_world_rig(lefts, rights, placements, pattern=pattern, square=placements.square,
                              max_rms_px=args.max_rms, leave_one_out=not args.no_loo, progress=progress)
    n_pairs = len(cal.pair_names)
    print(f"world-rig calibration: board found in {len(cal.used_pairs)} of {n_pairs} pairs "
          f"({pattern[0]}x{pattern[1]} corners, {placements.square:g} {placements.unit} squares)")
    for pair, reason in cal.skipped:
        ln, rn = cal.pair_names[pair]
        print(f"  skipped pair {pair} ({ln}, {rn}): {reason}")
    turned_l = sum(1 for v in cal.orientation_left.values() if v != "as detected")
    turned_r = sum(1 for v in cal.orientation_right.values() if v != "as detected")
    print(f"corner order resolved from the placements: {turned_l} left and {turned_r} right detections "
          "re-ordered")
    print(f"reprojection RMS: left {cal.rms_left:.3f} px, right {cal.rms_right:.3f} px")
    print(cal.table())
    print("(paper's Table 1: mean absolute error X 0.42, Y 0.36, Z 2.78 mm; std 0.35, 0.31, 1.74 mm)")
    rig = _with_working_distance(cal.rig, cal.fit_check)
    save_rig(rig, args.output, comment=(
        f"canopy-stereo calibrate --world-rig {placements_path}: Gold Standard from "
        f"{len(cal.used_pairs)} pairs; RMS left {cal.rms_left:.3f} px, right {cal.rms_right:.3f} px; "
        f"baseline {rig.baseline:.2f} {rig.world_unit}; working distance {_working_distance_text(rig)} "
        "(seen, with margin)"))
    print(f"wrote {args.output} (baseline {rig.baseline:.2f} {rig.world_unit}; working distance "
          f"{_working_distance_text(rig)}, the disparity range searched)")
    if args.plot:
        plot_world_rig_errors(cal, args.plot)
        print(f"wrote {args.plot}")
    return 0 if np.all(np.isfinite(cal.table1.mean_abs)) else 1


def _with_working_distance(rig, check):
    """The rig with ``near_m``/``far_m``: the distances the calibration saw, with margin
    (:func:`~canopy_stereo.geometry.calibration.observed_working_distance`)."""
    from canopy_stereo.geometry.calibration import observed_working_distance

    near_m, far_m = observed_working_distance(check, metres_per_unit=rig.metres_per_unit)
    return rig.with_extra(near_m=near_m, far_m=far_m)


def _working_distance_text(rig) -> str:
    return f"{rig.extra['near_m']:g} to {rig.extra['far_m']:g} m"


def _run_import(args) -> int:
    """``--from FORMAT FILES...``: another tool's calibration -> rig file."""
    from canopy_stereo.io.calibration_import import FORMATS, import_calibration

    fmt, *files = args.from_files
    if fmt not in FORMATS:
        raise CanopyStereoError(f"--from: unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not files:
        raise CanopyStereoError(f"--from {fmt} needs the calibration file(s) after the format")
    if args.unit is not None:
        check_world_unit(args.unit)
    size = None
    if args.image_size:
        size = parse_int_list(args.image_size, 2, "--image-size")
        for v in size:
            check_at_least(v, 1, "each of --image-size")
    rig = import_calibration(fmt, files, unit=args.unit, image_size=size)
    save_rig(rig, args.output, comment=f"canopy-stereo calibrate --from {fmt} {' '.join(files)}\n"
             f"world frame: the left camera's optical frame; baseline {rig.baseline:.4g} {rig.world_unit}")
    print(f"imported {fmt}: {rig.image_size[0]}x{rig.image_size[1]}, baseline {rig.baseline:.4g} "
          f"{rig.world_unit}, distortion {rig.distortion_model}")
    print(f"wrote {args.output}")
    return 0
