"""``canopy-stereo disparity``: dense disparity of a rectified pair to a PFM (and a PNG)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from canopy_stereo.disparity import DEFAULT_MATCHER, available_matchers, matcher_names, matcher_spec, preset_names
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import read_image, write_image
from canopy_stereo.io.pfm import write_pfm
from canopy_stereo.viz.colour import colorize_disparity, disparity_picture  # noqa: F401 - colorize_disparity re-exported

COMMAND = "disparity"
HELP = "dense disparity of a rectified pair (ELAS or SGBM) as a PFM"
DESCRIPTION = """Match the rectified pair LEFT/RIGHT and write the left disparity (pixels,
u_right = u_left - d) as a Middlebury-style PFM (float32, inf where invalid).
--png adds a colour-mapped picture with a colour bar in pixels (turbo from 0 to
--disp-max, or to the 99th percentile; near = red, invalid = black)."""

MATCHERS = tuple(matcher_names())


def add_arguments(p):
    p.add_argument("left", help="rectified left image")
    p.add_argument("right", help="rectified right image")
    p.add_argument("-o", "--output", required=True, metavar="DISP.pfm",
                   help="left disparity, PFM (inf = invalid)")
    p.add_argument("--matcher", choices=MATCHERS, default=DEFAULT_MATCHER,
                   help=f"matcher (default {DEFAULT_MATCHER})")
    specs = [matcher_spec(n) for n in available_matchers()]
    p.add_argument("--preset", choices=preset_names() or None, default=None,
                   help="preset of a matcher that has presets (default: " + ", ".join(
                       f"{s.default_preset} for {s.name}" for s in specs if s.presets) + ")")
    p.add_argument("--disp-min", type=int, default=0, metavar="N", help="smallest disparity (px)")
    p.add_argument("--disp-max", type=int, default=None, metavar="N",
                   help="largest disparity (px; default " + ", ".join(
                       f"{s.default_disp_max} for {s.name}" for s in specs) + ")")
    p.add_argument("--subpixel", action="store_true",
                   help="; ".join(s.parameter("subpixel").description for s in specs
                                  if any(q.name == "subpixel" for q in s.parameters)))
    p.add_argument("--png", metavar="VIS.png", help="also write a colour-mapped picture")


def run(args) -> int:
    spec = matcher_spec(args.matcher)
    names = {p.name for p in spec.parameters}
    if args.subpixel and "subpixel" not in names:
        raise CanopyStereoError(f"--subpixel does not apply to --matcher {args.matcher} (no subpixel parameter)")
    if args.preset is not None and not spec.presets:
        raise CanopyStereoError(f"--preset does not apply to --matcher {args.matcher} (it has no presets)")
    if not str(args.output).lower().endswith(".pfm"):
        raise CanopyStereoError(f"output must be a .pfm file, got {args.output}")
    from canopy_stereo.disparity import compute_disparity

    left, right = read_image(args.left), read_image(args.right)  # a bad file fails at once
    if spec.compiled:  # numba: compile outside the timing
        from canopy_stereo.cli.progress import warm_up_kernels

        warm_up_kernels()  # the time printed below is then the matching alone
    disp_max = args.disp_max if args.disp_max is not None else spec.default_disp_max
    params = {}
    if spec.presets:
        params["preset"] = args.preset or spec.default_preset
    if "subpixel" in names:
        params["subpixel"] = args.subpixel
    t0 = time.perf_counter()
    disp = compute_disparity(left, right, matcher=args.matcher, disp_min=args.disp_min,
                             disp_max=disp_max, **params)
    elapsed = time.perf_counter() - t0
    valid = disp >= 0
    out = np.where(valid, disp, np.inf).astype(np.float32)
    write_pfm(args.output, out)
    if args.png:
        top = float(args.disp_max) if args.disp_max else None
        write_image(Path(args.png), disparity_picture(np.where(valid, disp, np.nan), lo=0.0, hi=top,
                                                      title=f"{args.matcher} disparity"))
    h, w = disp.shape
    rng = f"{disp[valid].min():.1f}..{disp[valid].max():.1f}" if valid.any() else "none"
    print(f"{args.matcher}: {w}x{h}, density {100.0 * valid.mean():.1f}%, disparities {rng} px, "
          f"{1000.0 * elapsed:.0f} ms -> {args.output}" + (f", {args.png}" if args.png else ""))
    return 0

