"""``canopy-stereo run``: replay a bag through the ROS 2 node graph and record the outputs."""
from __future__ import annotations

from canopy_stereo.bag.split import add_split_arguments, split_options
from canopy_stereo.cli.common import check_at_least
from canopy_stereo.disparity import DEFAULT_MATCHER, default_matcher, matcher_names, matcher_spec
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.compressed_image import add_compression_arguments

COMMAND = "run"
HELP = "replay a stereo bag through the ROS 2 nodes and record their outputs"
DESCRIPTION = """Publish the bag's /stereo/left/image_raw and /stereo/right/image_raw (or, in a bag of
compressed images, their /compressed topics) into the
real nodes (rectify, disparity, segment, point cloud), built in this process on a private
DDS domain, and record /stereo/disparity, /stereo/points2, /stereo/left/mask and the camera
infos to OUT.mcap. --rate 0 plays as fast as the graph goes. Prints frames in/out, frames
per second and the latency from a raw pair to its point cloud. Needs ROS 2 Jazzy's rclpy."""


#: Largest DDS domain id every vendor accepts.
MAX_DOMAIN_ID = 232


def add_arguments(p):
    p.add_argument("--bag", required=True, metavar="BAG.mcap", help="input bag (rosbag2 MCAP)")
    p.add_argument("--rig", metavar="RIG.yaml",
                   help="rig file (ROS 2 parameter YAML; default: the rig recorded in the bag by bag_record --rig)")
    p.add_argument("--rate", type=float, default=1.0,
                   help="playback speed factor; 0 = as fast as the graph goes (default 1)")
    p.add_argument("--record", metavar="OUT.mcap", help="record the graph's outputs to this bag")
    p.add_argument("--matcher", choices=matcher_names(), default=None,
                   help=f"disparity matcher (default: {DEFAULT_MATCHER})")
    p.add_argument("--no-segment", action="store_true", help="do not run segment_node (no masks)")
    p.add_argument("--use-mask", action="store_true", help="keep only plant pixels in the clouds")
    p.add_argument("--organized", action="store_true", help="publish organized clouds (NaN = none)")
    p.add_argument("--no-skew-compensation", action="store_true",
                   help="pair the images as they came (rectify_node's skew_compensation false); by default "
                        "each right image is brought to its left image's instant along the right camera's motion")
    p.add_argument("--max-in-flight", type=int, default=2, metavar="N",
                   help="frames inside the graph at once with --rate 0 (default 2)")
    p.add_argument("--remap", nargs="*", default=[], metavar="FROM:=TO",
                   help="publish bag topics under other names, e.g. /cam/left:=/stereo/left/image_raw")
    p.add_argument("--domain-id", type=int, default=None,
                   help="DDS domain of the graph (default: a private one from the process id)")
    p.add_argument("--compression", choices=("lz4", "zstd", "none"), default="lz4",
                   help="chunk compression of the recorded bag (default lz4)")
    add_split_arguments(p)
    add_compression_arguments(p)
    p.add_argument("--view", action="store_true",
                   help="stream the outputs live to the Rerun viewer (extra 'viz'): a window, or the "
                        "web viewer on localhost when there is no display (served until Ctrl-C)")


def run(args) -> int:
    from canopy_stereo.ros import require_ros

    require_ros("canopy-stereo run")
    from canopy_stereo.ros.nodes.base import install_stop_signals

    install_stop_signals()  # SIGTERM/SIGHUP stop like Ctrl-C: the recording is closed validly
    import math

    from canopy_stereo.bag.metadata import RIG_RECORD, rig_from_bag
    from canopy_stereo.geometry.rig_rectification import rectification_for_rig
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.pipeline.reconstruct import disparity_range_for
    from canopy_stereo.ros.compressed import compression_from_args
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.player import parse_remaps
    from canopy_stereo.ros.runner import open_input_bag, run_bag

    if not (math.isfinite(args.rate) and args.rate >= 0):
        raise CanopyStereoError(f"--rate must be a finite number >= 0, got {args.rate}")
    check_at_least(args.max_in_flight, 1, "--max-in-flight")
    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        raise CanopyStereoError(f"--domain-id must be in 0..{MAX_DOMAIN_ID}, got {args.domain_id}")
    rig = load_rig(args.rig) if args.rig else rig_from_bag(args.bag)
    if rig is None:
        raise CanopyStereoError(f"{args.bag} has no '{RIG_RECORD}' metadata record: give the rig with --rig RIG.yaml")
    # the nodes read the rig's method and disparity range: check them here with the same
    # code as 'reconstruct' (one line and exit 2 instead of a graph that silently ignores them)
    try:
        disparity_range_for(rig, rectification_for_rig(rig))
    except CanopyStereoError as exc:
        raise CanopyStereoError(f"rig {args.rig or args.bag}: {exc}") from None
    options = GraphOptions(matcher=args.matcher, segment=not args.no_segment or args.use_mask,
                           use_mask=args.use_mask, organized=args.organized,
                           parameter_services=False,
                           node_parameters={"rectify_node": {"skew_compensation": not args.no_skew_compensation}})
    # a bag the graph cannot play fails before the kernels are prepared (one line, no wait)
    open_input_bag(args.bag, namespace=options.namespace, remap=parse_remaps(args.remap))
    if matcher_spec(args.matcher or default_matcher()).compiled:
        from canopy_stereo.cli.progress import warm_up_kernels

        warm_up_kernels()  # says so when numba compiles (first run)
    view = None
    if args.view:
        from pathlib import Path

        from canopy_stereo.ros.viewer import LiveView

        view = LiveView(rig, name=Path(args.bag).stem, need_mask=options.segment)
    try:
        result = run_bag(args.bag, rig, rate=args.rate, record=args.record, options=options,
                         domain_id=args.domain_id, max_in_flight=args.max_in_flight,
                         remap=parse_remaps(args.remap), compression=args.compression,
                         extra_outputs=view.extra_outputs if view else None,
                         on_output=view.on_output if view else None,
                         image_compression=compression_from_args(args), **split_options(args))
        for line in result.summary_lines():
            print(line, flush=True)
    finally:
        if view is not None:
            view.finish()
    return 0 if result.frames_out > 0 or result.frames_in == 0 else 1
