"""``canopy-stereo demo``: the bundled bags through the ROS 2 node graph -> PLY, disparity PNG, summary."""
from __future__ import annotations

from pathlib import Path

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
    p.add_argument("--matcher", choices=("elas", "sgbm"), default=None,
                   help="disparity matcher (default: elas)")
    p.add_argument("--domain-id", type=int, default=None, help="DDS domain (default: private)")


def run(args) -> int:
    from canopy_stereo.ros import require_ros

    require_ros("canopy-stereo demo")
    from canopy_stereo.ros.nodes.base import install_stop_signals

    install_stop_signals()  # SIGTERM/SIGHUP stop like Ctrl-C (no half-written outputs left open)
    from canopy_stereo.ros.demo import run_scene

    out_dir = Path(args.out)
    scenes = SCENES if args.scene == "all" else (args.scene,)
    for scene in scenes:
        for line in run_scene(scene, out_dir, args.matcher, args.domain_id):
            print(line, flush=True)
    return 0
