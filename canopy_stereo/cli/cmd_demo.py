"""``canopy-stereo demo``: the bundled bags through the ROS 2 node graph -> PLY, disparity PNG, summary."""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names
from canopy_stereo.ros.bundled import BUNDLED

COMMAND = "demo"
HELP = "run the bundled bags (synthetic croton, Middlebury Plants) through the ROS 2 graph"
DESCRIPTION = """Replay each bundled bag (bags/croton.mcap through the paper's rig,
bags/plants.mcap: Middlebury 2014 Plants) through the real nodes, as `canopy-stereo run`
does, and write OUT/<scene>.ply (the first frame's metric cloud, metres, RGB),
OUT/<scene>_disparity.png (colour-coded, invalid black), OUT/<scene>_mask.png (GrabCut)
and OUT/<scene>_summary.txt. For the croton the depth error against the scene's truth is
reported. Needs ROS 2 Jazzy's rclpy."""

SCENES = tuple(BUNDLED)


def add_arguments(p):
    p.add_argument("--scene", choices=SCENES + ("all",), default="all", help="bag to run (default all)")
    p.add_argument("--out", default="out", metavar="DIR", help="output folder (default out/)")
    p.add_argument("--matcher", choices=matcher_names(), default=None,
                   help=f"disparity matcher (default: {DEFAULT_MATCHER})")
    p.add_argument("--domain-id", type=int, default=None, help="DDS domain (default: private)")
    p.add_argument("--compressed", action="store_true",
                   help="replay the bags with their images as JPEG (quality 95) CompressedImage on "
                        "<topic>/compressed, as robot bags hold them")
    p.add_argument("--view", action="store_true",
                   help="stream the outputs live to the Rerun viewer (extra 'viz'): a window, or the "
                        "web viewer on localhost when there is no display (served until Ctrl-C)")


def run(args) -> int:
    from canopy_stereo.ros import require_ros

    require_ros("canopy-stereo demo")
    from canopy_stereo.ros.nodes.base import install_stop_signals

    install_stop_signals()  # SIGTERM/SIGHUP stop like Ctrl-C (no half-written outputs left open)
    from canopy_stereo.cli.progress import warm_up_kernels
    from canopy_stereo.ros.demo import run_scene

    warm_up_kernels()  # says so when numba compiles (first run), so that the speed excludes it
    out_dir = Path(args.out)
    scenes = SCENES if args.scene == "all" else (args.scene,)
    view = None
    if args.view:
        from canopy_stereo.io.rig import load_rig
        from canopy_stereo.ros.bundled import bundled_rig
        from canopy_stereo.ros.viewer import LiveView

        view = LiveView(load_rig(bundled_rig(scenes[0])), name=scenes[0], need_mask=True)
    try:
        for k, scene in enumerate(scenes):
            if view is not None and k > 0:
                view.start_recording(scene, load_rig(bundled_rig(scene)))
            for line in run_scene(scene, out_dir, matcher=args.matcher, domain_id=args.domain_id, view=view,
                                  compressed=args.compressed):
                print(line, flush=True)
    finally:
        if view is not None:
            view.finish()
    return 0
