"""``canopy-stereo features``: the paper's feature-matching study on your own pair."""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import check_pair, read_image

COMMAND = "features"
HELP = "compare feature matchers on a stereo pair (the paper's Tables 2-4)"
DESCRIPTION = """Match LEFT and RIGHT with each method and print the paper's columns:
t1/num1 (left detection time and features), t2/num2 (right), t (matching and
verification), propagation and resample (qdmatch only), num (verified matches) and
distribution (share of 8x8-pixel cells of the left image holding a match). With
--gt (a ground-truth disparity of a rectified pair) the last column is the share of
matches within 1 px of the truth; without it, the share within 1 px of the
epipolar line of F fitted to all methods' matches. Methods the installed OpenCV
lacks (SURF: patented; AKAZE/KAZE in OpenCV 5) get an empty row that says so."""

_DEFAULT = "harris-affine,hessian-affine,sift,asift,surf,orb,akaze,qdmatch"


def add_arguments(p):
    p.add_argument("left", help="left image")
    p.add_argument("right", help="right image")
    p.add_argument("--methods", default=_DEFAULT, metavar="M1,M2,...",
                   help=f"comma-separated methods (default {_DEFAULT}; also kaze)")
    p.add_argument("--gt", metavar="DISP", help="ground-truth left disparity (PFM, or PNG/PGM "
                   "with --gt-scale) of a rectified pair")
    p.add_argument("--gt-scale", type=float, default=None, metavar="S",
                   help="integer GT images store S x disparity (Middlebury 2003 quarter: 4, "
                        "2006 third: 3, Tsukuba: 16); 0 = unknown")
    p.add_argument("--csv", metavar="TABLE.csv", help="write the table as CSV")
    p.add_argument("--matches-out", metavar="DIR",
                   help="write <method>.csv (x_left,y_left,x_right,y_right) per method")
    p.add_argument("--plot", metavar="SPREAD.png", help="save the matches' spread per method")


def run(args) -> int:
    from canopy_stereo.features.study import (
        format_table,
        parse_methods,
        plot_spread,
        run_study,
        write_csv,
        write_matches,
    )

    methods = parse_methods(args.methods)
    left, right = read_image(args.left), read_image(args.right)
    check_pair(left, right)
    gt = None
    if args.gt:
        from canopy_stereo.io.middlebury import read_disparity

        if not Path(args.gt).suffix.lower() == ".pfm" and not args.gt_scale:
            raise CanopyStereoError(f"--gt {args.gt} is an integer image: give --gt-scale "
                                    "(stored value / disparity)")
        gt = read_disparity(args.gt, args.gt_scale)

    from canopy_stereo.progress import Progress

    with Progress(len(methods), "matching with method") as bar:  # on a terminal only
        rows = run_study(left, right, methods=methods, gt_disparity=gt, progress=bar.step)
    print(format_table(rows))
    if args.csv:
        print(f"table written to {write_csv(rows, args.csv)}")
    if args.matches_out:
        for row in rows:
            write_matches(row.result, args.matches_out)
        print(f"matches written to {args.matches_out}/<method>.csv")
    if args.plot:
        print(f"spread plot written to {plot_spread(rows, left, args.plot)}")
    return 0
