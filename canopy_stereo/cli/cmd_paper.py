"""``canopy-stereo paper``: reproduce Ni & Burks on the shipped data, as a Markdown report."""
from __future__ import annotations

import sys

COMMAND = "paper"
HELP = "reproduce the paper's tables and figures on the shipped data (Markdown report)"
DESCRIPTION = """Run the paper's experiments on what the package ships and write DIR/report.md
with this run's numbers next to the paper's printed ones, plus its figures (PNG):
Table 1 and Figure 5 (world-rig calibration on rendered photographs of the paper's
layout), Tables 2-4 (feature study on the bundled Plants pair and the synthetic
citrus branch and croton, with correctness against the exact correspondences),
Figure 11 (epipolar lines before/after Hartley rectification), Figures 15-17
(rectified pairs and reconstructed clouds) and the two marked croton leaves. Also
writes report.json (the numbers), tables/*.csv, matches/<scene>/<method>.csv and
clouds/*.ply. Progress goes to stderr. --quick is the reduced mode used by CI."""


def add_arguments(p):
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    p.add_argument("--quick", action="store_true",
                   help="reduced mode: methods sift,asift,qdmatch and 9 of the 45 calibration placements")
    p.add_argument("--seed", type=int, default=0, help="seed of the rendered scenes (default 0)")
    p.add_argument("--methods", metavar="M1,M2,...",
                   help="feature methods of Tables 2-4 (default: all; --quick: sift,asift,qdmatch)")
    p.add_argument("--no-calibration", action="store_true", help="skip Table 1 / Figure 5")
    p.add_argument("--quiet", action="store_true", help="no progress messages")


def run(args) -> int:
    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.features.study import parse_methods
    from canopy_stereo.pipeline.paper import run_paper
    from canopy_stereo.progress import Progress

    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise CanopyStereoError("the paper's figures need matplotlib: pip install "
                                "'canopy_stereo[plot]'") from None
    methods = parse_methods(args.methods) if args.methods else None
    progress = Progress(7, stream=sys.stderr, lines=True, force=not args.quiet)
    numbers = run_paper(args.output, quick=args.quick, seed=args.seed, methods=methods,
                        progress=progress, calibration=not args.no_calibration)
    print(f"report written to {args.output}/report.md ({numbers['timings_s']['total']:.1f} s)")
    return 0
