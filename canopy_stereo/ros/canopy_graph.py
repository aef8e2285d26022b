"""The ``canopy_graph`` executable: the node graph of :mod:`canopy_stereo.ros.graph` in one process.

``canopy_graph`` (``ros2 run canopy_stereo canopy_graph --rig RIG.yaml``) runs
it from live cameras (``--cameras LEFT RIGHT``, or ``--stereo-camera DEVICE --layout
side_by_side|top_bottom`` for a one-device stereo webcam) or from a bag (``--bag``, replayed by
:func:`canopy_stereo.ros.runner.run_bag`), optionally recording the outputs
(``--record``; ``--compress-images`` stores the images as image_transport's
``<topic>/compressed``: the cameras' own JPEG, masks as PNG; with ``--loop`` every pass
appends to the same recording, which
``--split-size`` and ``--split-duration`` split into ``<name>_0.mcap``, ... as
rosbag2 does). SIGINT, SIGTERM and SIGHUP close the recording validly.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time

from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.compressed_image import add_compression_arguments
from canopy_stereo.ros.compressed import compression_from_args
from canopy_stereo.ros.context import tune_node_process
from canopy_stereo.ros.graph import DEFAULT_THREADS, EXECUTOR_CHOICES, CanopyGraph, GraphOptions
from canopy_stereo.ros.player import add_playback_arguments
from canopy_stereo.ros.runner import run_bag


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="canopy_graph",
        description="All canopy_stereo nodes in one process, from live cameras or a bag.")
    p.add_argument("--rig", required=True, metavar="RIG.yaml", help="rig file (ROS 2 parameter YAML)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--bag", metavar="BAG.mcap", help="replay this bag's left/right image_raw")
    src.add_argument("--stereo-camera", metavar="DEVICE",
                     help="one device delivering both views in one frame (a synchronized stereo webcam; "
                          "--layout)")
    src.add_argument("--cameras", nargs=2, metavar=("LEFT", "RIGHT"),
                     help="camera devices (V4L2 index, /dev path, video file or image pattern)")
    add_playback_arguments(p, loop_help="replay the bag until Ctrl-C (the nodes are built once and follow "
                                        "the stamps jumping back at every pass)")
    p.add_argument("--fps", type=float, default=15.0, help="camera frame rate")
    p.add_argument("--width", type=int, default=0, help="camera width (default: the rig's)")
    p.add_argument("--height", type=int, default=0, help="camera height (default: the rig's)")
    p.add_argument("--fourcc", default="", help="camera pixel format, e.g. MJPG")
    p.add_argument("--layout", choices=("side_by_side", "top_bottom"), default="side_by_side",
                   help="--stereo-camera: left view in the left half (side_by_side) or on top")
    p.add_argument("--record", metavar="OUT.mcap", help="record the outputs")
    from canopy_stereo.bag.split import add_split_arguments

    add_split_arguments(p)
    add_compression_arguments(p)
    p.add_argument("--metadata", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                   help="with --cameras --record: describe the recording (plant_id=A12 plot=row1 ...); "
                        "stored with the rig file as the bag's metadata records")
    p.add_argument("--matcher", choices=matcher_names(), default=None,
                   help=f"disparity matcher (default: {DEFAULT_MATCHER})")
    p.add_argument("--use-mask", action="store_true", help="keep only plant pixels in the clouds")
    p.add_argument("--no-segment", action="store_true", help="do not run segment_node")
    p.add_argument("--traits", action="store_true",
                   help="run traits_node: live traits (JSON on traits, boxes and labels on traits/markers)")
    p.add_argument("--segment-depth-cue", action="store_true",
                   help="segment_node seeds GrabCut with the disparity too (near = plant)")
    p.add_argument("--organized", action="store_true", help="organized clouds")
    p.add_argument("--namespace", default="/stereo",
                   help="namespace of the nodes and topics (default /stereo); a bag recorded under "
                        "another one (the bundled /stereo/... bags) is played into this one")
    m = p.add_argument_group("mounting on a robot (REP 105; rectify_node's parameters)")
    m.add_argument("--parent-frame", default="", metavar="FRAME",
                   help="robot frame the rig is mounted on, e.g. base_link or tool0")
    mount = m.add_mutually_exclusive_group()
    mount.add_argument("--mount", nargs=7, type=float, metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                       help="the rig's world frame in --parent-frame (metres, unit quaternion)")
    mount.add_argument("--camera-mount", nargs=7, type=float, metavar=("X", "Y", "Z", "QX", "QY", "QZ", "QW"),
                       help="the raw left camera's optical frame in --parent-frame (hand-eye calibration)")
    m.add_argument("--frame-prefix", default="", metavar="PREFIX",
                   help="prepended to every frame the rig names, e.g. rig_a/ (two rigs in one TF tree)")
    m.add_argument("--no-tf", action="store_true",
                   help="publish (and record) no /tf_static: the robot's URDF owns the camera frames")
    p.add_argument("--executor", choices=EXECUTOR_CHOICES, default="per-node",
                   help="one single-threaded executor per node (default) or one multi-threaded one")
    p.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                   help="threads of the multi-threaded executor")
    p.add_argument("--recut-every", type=int, default=None, metavar="N",
                   help="segment_node: a full GrabCut every N frames, the plant model propagated between "
                        "(default 10; 1 = every frame)")
    p.add_argument("--disparity-threads", type=int, default=None, metavar="N",
                   help="disparity_node: threads of the matcher (default: the node's)")
    p.add_argument("--no-intra-process", action="store_true",
                   help="pass messages between the nodes through DDS too (default: the message objects, "
                        "canopy_stereo.ros.intra_process)")
    return p


def _print_pass(passes: int, frames_in: int, frames_out: int) -> None:
    """One line per pass of ``--loop`` (the totals so far)."""
    print(f"frames in: {frames_in}, frames out: {frames_out} (after pass {passes})", flush=True)


def _run_bag_until_interrupted(opts, rig, options: GraphOptions, context, record=None):
    """Play ``opts.bag`` (``--loop``: until Ctrl-C) through one graph; the playback runs in a
    worker thread so that the main thread takes the signal and stops it cleanly."""
    stop, done = threading.Event(), threading.Event()
    outcome: dict = {}

    def work():
        try:
            outcome["result"] = run_bag(opts.bag, rig, rate=opts.rate, record=record, options=options,
                                        context=context, loop=opts.loop, stop=stop, on_pass=_print_pass,
                                        image_compression=compression_from_args(opts))
        except BaseException as exc:  # noqa: BLE001 - re-raised in the main thread
            outcome["error"] = exc
        finally:
            done.set()

    worker = threading.Thread(target=work, name="canopy_graph:bag", daemon=True)
    worker.start()
    # poll with sleep: a KeyboardInterrupt inside Thread.join() can leave the thread marked as
    # finished while it still runs (CPython 3.11)
    try:
        while not done.is_set():
            time.sleep(0.1)
    except KeyboardInterrupt:
        stop.set()
    while not done.is_set():
        time.sleep(0.1)
    worker.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["result"]


def main(args=None) -> int:
    """``canopy_graph`` executable (``--ros-args`` after the options are passed to every node)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.context import init_executable_ros, parse_executable_args
    from canopy_stereo.ros.nodes.base import install_stop_signals

    argv = sys.argv if args is None else args
    opts = parse_executable_args("canopy_graph", build_parser(), argv)
    if opts is None:
        return 2
    if opts.metadata and not ((opts.cameras or opts.stereo_camera) and opts.record):
        print("canopy_graph: error: --metadata describes a recording from cameras: use it with "
              "--cameras and --record", file=sys.stderr)
        return 2
    options = GraphOptions(namespace=opts.namespace, matcher=opts.matcher,
                           segment=not opts.no_segment or opts.use_mask, use_mask=opts.use_mask,
                           segment_depth_cue=opts.segment_depth_cue, organized=opts.organized,
                           threads=opts.threads, executor=opts.executor, recut_every=opts.recut_every,
                           disparity_threads=opts.disparity_threads, intra_process=not opts.no_intra_process,
                           traits=opts.traits,
                           parent_frame=opts.parent_frame, mount=opts.mount, camera_mount=opts.camera_mount,
                           publish_tf=not opts.no_tf, frame_prefix=opts.frame_prefix)
    if (opts.mount or opts.camera_mount) and not opts.parent_frame:
        print("canopy_graph: error: --mount/--camera-mount need --parent-frame", file=sys.stderr)
        return 2
    if opts.cameras or opts.stereo_camera:
        # free-running cameras: the pairing tolerance is half a frame period at the camera rate
        if not opts.fps > 0:
            print("canopy_graph: error: --fps must be > 0", file=sys.stderr)
            return 2
        # (CanopyGraph gives rectify_node the cameras' fps: pairing within half a frame period)
    tune_node_process()
    if not init_executable_ros("canopy_graph", argv):  # a bad --params-file or --ros-args: one line
        return 2
    install_stop_signals()
    context = rclpy.get_default_context()
    graph = recorder = writer = None
    try:
        rig = load_rig(opts.rig)
        compression = compression_from_args(opts)  # checks --jpeg-quality
        if opts.record:
            from canopy_stereo.bag import BagWriter
            from canopy_stereo.bag.split import split_options

            # one writer for every pass of --loop: passes append (or split), never overwrite
            writer = BagWriter(opts.record, compression="lz4", **split_options(opts))
        if opts.bag:
            result = _run_bag_until_interrupted(opts, rig, options, context, record=writer)
            print("\n".join(result.summary_lines()), flush=True)
            return 0
        w = opts.width or rig.image_size[0]
        h = opts.height or rig.image_size[1]
        cam = {"width": w, "height": h, "fps": float(opts.fps), "fourcc": opts.fourcc}
        if opts.record and compression is not None:  # the cameras' own JPEG is recorded (a device's MJPEG as is)
            cam.update(transport="both", jpeg_quality=compression.quality)
        if opts.stereo_camera:  # one capture holds both views: twice the width (or height)
            wide = opts.layout == "side_by_side"
            cameras: tuple = ({**cam, "width": w * (2 if wide else 1), "height": h * (1 if wide else 2),
                               "device": str(opts.stereo_camera), "layout": opts.layout},)
        else:
            cameras = ({**cam, "device": str(opts.cameras[0])}, {**cam, "device": str(opts.cameras[1])})
        graph = CanopyGraph(rig, context, options, cameras=cameras)
        if opts.record:
            from canopy_stereo.ros.recorder import BagRecorder

            ns = "/" + options.namespace.strip("/")
            topics = [f"{ns}/{t}" for t in (*options.output_topics(), "left/camera_info", "right/camera_info",
                                             "left/image_raw", "right/image_raw")]
            if compression is not None:
                topics = [t + "/compressed" if t.endswith("/image_raw") else t for t in topics]
            from canopy_stereo.bag.metadata import parse_key_values, recording_metadata

            for name, data in recording_metadata(parse_key_values(opts.metadata), rig).items():
                writer.add_metadata(name, data)
            recorder = BagRecorder(writer, topics, context=context, compression=compression,
                                   static_transforms=graph.nodes["rectify_node"].tf_transforms)
            graph.add_node(recorder)
        graph.spin_until_interrupted()
        return 0
    except CanopyStereoError as exc:
        print(f"canopy_graph: error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        try:
            if graph is not None:  # stops every executor, the recorder's too
                graph.shutdown()
        finally:  # the recording is closed even if a second signal cut the shutdown short
            if recorder is not None:
                recorder.close()
                recorder.destroy_node()
            if writer is not None:
                writer.close()
                print(f"canopy_graph: recorded {', '.join(str(p) for p in writer.paths)}", flush=True)
            if rclpy.ok():
                rclpy.shutdown()


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
