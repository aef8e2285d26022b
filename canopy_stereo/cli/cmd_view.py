"""``canopy-stereo view``: look at a bag (raw frames or recorded outputs) or a saved recording in Rerun."""
from __future__ import annotations

import shutil
from pathlib import Path

from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names
from canopy_stereo.errors import CanopyStereoError

COMMAND = "view"
HELP = "show a bag or a saved recording in the Rerun viewer (native window, browser or .rrd file)"
DESCRIPTION = """Show per frame, on one timeline of header stamps: the coloured cloud in the
world frame (metres), the left rectified image, the depth with the rectified camera's pinhole
and pose (image and cloud line up), the plant mask, and the measured leaves (outline, length x
width) and canopy box and height.

SOURCE is a bag of raw frames (<ns>/left/image_raw, <ns>/right/image_raw, or only their /compressed
topics: run through the node
graph; rig from --rig, else from the bag's 'canopy_stereo' metadata record), a bag of recorded
outputs (<ns>/points2 ...: shown as recorded), or a saved recording (.rrd).
--save writes a recording file and exits; --web serves the web viewer (shipped in the rerun-sdk
wheel) on http://127.0.0.1:PORT until Ctrl-C, for headless machines and field laptops;
otherwise a native viewer window opens. Needs the optional extra 'viz' (rerun-sdk)."""


def add_arguments(p):
    p.add_argument("source", metavar="BAG.mcap|REC.rrd", help="bag (raw frames or recorded outputs) or .rrd")
    p.add_argument("--rig", metavar="RIG.yaml", help="rig file (default: the rig stored in the bag)")
    p.add_argument("--save", metavar="OUT.rrd", help="write the recording to this file and exit")
    p.add_argument("--web", action="store_true",
                   help="serve the web viewer on localhost instead of opening a window")
    p.add_argument("--port", type=int, default=None, metavar="N",
                   help="with --web: HTTP port of the viewer page (default 9090)")
    p.add_argument("--no-measure", action="store_true",
                   help="do not measure leaves and canopy per frame (faster; recorded bags are measured "
                        "only when their clouds are organized and masks were recorded)")
    p.add_argument("--matcher", choices=matcher_names(), default=None,
                   help=f"disparity matcher for raw bags (default: {DEFAULT_MATCHER})")
    p.add_argument("--domain-id", type=int, default=None, help="DDS domain of the graph (default: private)")


def _check(args) -> Path:
    from canopy_stereo.viz import INSTALL_HINT, rerun_available

    if not rerun_available():
        raise CanopyStereoError(INSTALL_HINT)
    src = Path(args.source)
    if not src.is_file():
        raise CanopyStereoError(f"no such file: {src}")
    if args.port is not None and not args.web:
        raise CanopyStereoError("--port needs --web")
    if args.port is not None and not 1 <= args.port <= 65535:
        raise CanopyStereoError(f"--port must be 1..65535, got {args.port}")
    if args.save and args.web:
        raise CanopyStereoError("choose one of --save and --web")
    if args.save and not str(args.save).endswith(".rrd"):
        raise CanopyStereoError(f"--save must name a .rrd file, got {args.save}")
    return src


def run(args) -> int:
    src = _check(args)
    if src.suffix == ".rrd":
        return _show_rrd(src, args)
    return _show_bag(src, args)


def _show_rrd(src: Path, args) -> int:
    import subprocess

    from canopy_stereo.viz.rerun_log import has_display, rerun_command, serve_web

    if args.rig:
        raise CanopyStereoError("--rig applies to bags, not to a saved recording")
    if args.save:
        shutil.copyfile(src, args.save)
        print(f"wrote {args.save}")
        return 0
    if args.web:
        web = serve_web(port=args.port or 9090, files=[src])
        print(f"viewer: {web.url}", flush=True)
        try:
            web.serve_until_interrupted()
        finally:
            web.stop()
        return 0
    if not has_display():
        raise CanopyStereoError("no display for a viewer window here: use --web (serve the viewer "
                                "to a browser)")
    return subprocess.call(rerun_command() + [str(src)])


def _show_bag(src: Path, args) -> int:
    from canopy_stereo.ros import require_ros

    require_ros("canopy-stereo view")
    from canopy_stereo.bag import BagReader
    from canopy_stereo.bag.metadata import RIG_RECORD, rig_from_bag
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.viewer import bag_kind, run_raw_bag, show_recorded_outputs
    from canopy_stereo.viz.rerun_log import FrameLogger, close_recording, open_recording, serve_web

    bag = BagReader(src)
    kind, ns = bag_kind(bag)
    rig = load_rig(args.rig) if args.rig else rig_from_bag(src)
    if kind == "raw" and rig is None:
        raise CanopyStereoError(f"{src} holds raw frames but no rig (no '{RIG_RECORD}' metadata "
                                "record): give the rig with --rig RIG.yaml")
    if kind == "raw" and ns != "/stereo":
        raise CanopyStereoError(f"{src}: raw frames under {ns}/, the graph reads /stereo/left/image_raw "
                                "and /stereo/right/image_raw")
    web = serve_web(port=args.port or 9090) if args.web else None
    if web is not None:
        print(f"viewer: {web.url}", flush=True)
    done = False
    try:
        rec = open_recording(save=args.save, web=web, spawn=not (args.save or args.web),
                             name=src.stem, with_measurements=not args.no_measure)
        logger = FrameLogger(rec, with_measurements=not args.no_measure)
        try:
            if kind == "raw":
                from canopy_stereo.cli.progress import warm_up_kernels
                from canopy_stereo.progress import Progress

                warm_up_kernels()
                left = f"{ns}/left/image_raw"
                total = (bag.topics.get(left) or bag.topics[f"{left}/compressed"]).message_count
                with Progress(total, "frames shown") as bar:  # on a terminal only
                    result = run_raw_bag(src, rig, logger, measure=not args.no_measure, matcher=args.matcher,
                                         domain_id=args.domain_id, on_logged=lambda: bar.step())
                print(f"{src}: {result.frames_in} frames through the graph, {logger.frames} shown")
                _print_first_measurement(result.viewer_measurements)
            else:
                measured: list = []
                n = show_recorded_outputs(bag, ns, logger, rig=rig, measure=not args.no_measure,
                                          measurements=measured)
                print(f"{src}: {n} recorded frames shown" + ("" if rig else " (no rig: camera pose unknown)"))
                _print_first_measurement(sorted(measured, key=lambda m: m[0]))
        finally:
            close_recording(rec)
        done = True
        if args.save:
            print(f"wrote {args.save}")
        elif web is not None:
            web.serve_until_interrupted()
    finally:
        if web is not None:
            web.stop()
        if args.save and not done:
            Path(args.save).unlink(missing_ok=True)  # no half-written recording is left behind
    return 0 if logger.frames > 0 else 1


def _print_first_measurement(measurements) -> None:
    """The first measured frame's summary (the one measuring pipeline's lines: mm, cm^2, cm^3)."""
    from canopy_stereo.measure.plant import measurement_lines

    for k, (_, report) in enumerate(measurements):
        if report is not None:
            print(f"frame {k + 1} of {len(measurements)}:")
            for line in measurement_lines(report):
                print("  " + line)
            return
