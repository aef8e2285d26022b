"""CPU per message of the downstream nodes' per-message paths, offline, in one process.

``disparity_node`` (without its matcher), ``segment_node`` and ``point_cloud_node`` of the
masked graph get the messages ``benchmarks/bench_graph.py`` sends them (the Plants frames,
rectified, matched by ELAS and segmented once beforehand) by direct calls of their
subscription callbacks (no executor, no other process: the figures are the nodes' own
Python/numba work plus rclpy's publish; a publish has no subscriber here). ``take`` is
rclpy's deserialisation of the node's input messages (what its executor does before the
callbacks: ``rclpy.serialization.deserialize_message``), reported apart; inputs a node reads
as views of the serialized message (``raw`` subscriptions) are given as bytes, their
parsing counted in the callbacks.

    .venv/bin/python benchmarks/bench_node_paths.py --size 1280x720 --frames 30

Prints, per node, CPU ms per frame: the callbacks (disparity_node: minus the matcher's own
CPU, measured around ``compute_disparity``/``disparity_in_window``) and the take.
The machine is shared: quote figures with the load (printed).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.append(str(Path(__file__).resolve().parents[1]))  # the checkout (the installed package wins)


def build_messages(size: str, n: int):
    """Messages of ``n`` frames: per frame a dict of topic -> message."""
    import cv2
    from bench_graph import bench_frames  # type: ignore[import-not-found]

    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.geometry.frames import FrameNames, stereo_transforms
    from canopy_stereo.geometry.rectification import fusiello_rectify, metric_disparity_range, rectify_pair
    from canopy_stereo.ros.convert import disparity_to_msg, image_to_msg, rectified_camera_info
    from canopy_stereo.ros.stereo_geometry import stereo_geometry_msg
    from canopy_stereo.segmentation.propagate import DEFAULT_MAX_PIXELS, MaskPropagator

    rig, frames = bench_frames("plants", size, n_frames=n)
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    baseline_m = rect.baseline * rig.metres_per_unit
    f = float(rect.K_rect_left[0, 0])
    lo, hi = metric_disparity_range(f, baseline_m)
    names = FrameNames()
    geometry = stereo_geometry_msg(rig, rect, names, transforms=stereo_transforms(rig, rect, names=names))
    propagator = MaskPropagator(max_pixels=DEFAULT_MAX_PIXELS)
    out = []
    for i, (left, right) in enumerate(frames[:n]):
        stamp = (i + 1) * 33_333_333
        rl, rr = rectify_pair(left, right, rig, rect)
        gl, gr = cv2.cvtColor(rl, cv2.COLOR_BGR2GRAY), cv2.cvtColor(rr, cv2.COLOR_BGR2GRAY)
        disp = compute_disparity(gl, gr, matcher="elas", disp_min=lo, disp_max=hi)
        mask = propagator.segment(rl)
        info_l = rectified_camera_info(rect.K_rect_left, rect.size, baseline_m, "left", stamp_ns=stamp,
                                       frame_id=names.rect_left)
        info_r = rectified_camera_info(rect.K_rect_right, rect.size, baseline_m, "right", stamp_ns=stamp,
                                       frame_id=names.rect_right)
        out.append({
            "colour": image_to_msg(rl, "bgr8", stamp_ns=stamp, frame_id=names.rect_left),
            "left": image_to_msg(gl, "mono8", stamp_ns=stamp, frame_id=names.rect_left),
            "right": image_to_msg(gr, "mono8", stamp_ns=stamp, frame_id=names.rect_right),
            "info_l": info_l, "info_r": info_r,
            "disparity": disparity_to_msg(disp, f, baseline_m, lo, hi, stamp_ns=stamp, frame_id=names.rect_left),
            "mask": image_to_msg(mask, "mono8", stamp_ns=stamp, frame_id=names.rect_left),
        })
    return out, geometry


def take_ms(frames, topics) -> float:
    """CPU ms per frame rclpy spends deserialising ``topics`` of each frame (a node's raw
    subscriptions are left out by the callers: their parsing is in the callbacks' figure)."""
    from rclpy.serialization import deserialize_message, serialize_message

    blobs = [[(type(fr[t]), serialize_message(fr[t])) for t in topics] for fr in frames]
    t0 = time.process_time()
    for row in blobs:
        for cls, blob in row:
            deserialize_message(blob, cls)
    return (time.process_time() - t0) * 1e3 / len(frames)


def cached_messages(size: str, n: int, cache: str | None):
    """:func:`build_messages`, kept serialised in ``cache`` (a file) between runs."""
    import pickle

    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import CameraInfo, Image
    from std_msgs.msg import String
    from stereo_msgs.msg import DisparityImage

    types = {"colour": Image, "left": Image, "right": Image, "mask": Image, "info_l": CameraInfo,
             "info_r": CameraInfo, "disparity": DisparityImage}
    path = Path(cache) if cache else None
    if path is not None and path.exists():
        blobs, geometry = pickle.loads(path.read_bytes())
        if len(blobs) >= n:
            return ([{k: deserialize_message(v, types[k]) for k, v in fr.items()} for fr in blobs[:n]],
                    deserialize_message(geometry, String))
    frames, geometry = build_messages(size, n)
    if path is not None:
        path.write_bytes(pickle.dumps(([{k: serialize_message(v) for k, v in fr.items()} for fr in frames],
                                       serialize_message(geometry))))
    return frames, geometry


def bench(size: str, n: int, repeat: int, cache: str | None = None) -> None:
    import rclpy
    from rclpy.parameter import Parameter

    from canopy_stereo.ros.context import private_domain_id, tune_memory_allocator, tune_opencv_threads
    from canopy_stereo.ros.nodes import disparity as disparity_module
    from canopy_stereo.ros.nodes.disparity import DisparityNode
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode
    from canopy_stereo.ros.nodes.segment import SegmentNode

    tune_memory_allocator()  # as in a node process (run_node)
    tune_opencv_threads()
    frames, geometry = cached_messages(size, n, cache)
    w, h = frames[0]["colour"].width, frames[0]["colour"].height
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=private_domain_id())
    size_params = [Parameter("image_width", value=w), Parameter("image_height", value=h)]
    results = {}
    try:
        # ---- point_cloud_node (masked)
        node = PointCloudNode(context=context, parameter_overrides=[Parameter("use_mask", value=True)])
        node._on_geometry(geometry)
        calls = (("disparity", node.sub_disp), ("colour", node.sub_color), ("info_l", node.sub_info),
                 ("mask", node.sub_mask))
        results["point_cloud_node"] = _time_calls(node, frames, calls, repeat, "clouds_published")
        results["point_cloud_node"]["take"] = take_ms(frames, [t for t, s in calls if not s.raw])
        node.destroy_node()
        # ---- segment_node (follow_disparity, as in the masked graph)
        node = SegmentNode(context=context, parameter_overrides=[Parameter("follow_disparity", value=True)])
        calls = (("colour", node.sub), ("disparity", node.sub_disp))
        results["segment_node"] = _time_calls(node, frames, calls, repeat, "masks_published")
        results["segment_node"]["take"] = take_ms(frames, [t for t, s in calls if not s.raw])
        node.destroy_node()
        # ---- disparity_node (roi), the matcher's CPU subtracted
        matcher_cpu = [0.0]

        def timed(fn):
            def wrapper(*args, **kwargs):
                t0 = time.process_time()
                try:
                    return fn(*args, **kwargs)
                finally:
                    matcher_cpu[0] += time.process_time() - t0
            return wrapper

        originals = disparity_module.compute_disparity, disparity_module.disparity_in_window
        disparity_module.compute_disparity = timed(originals[0])
        disparity_module.disparity_in_window = timed(originals[1])
        try:
            node = DisparityNode(context=context, parameter_overrides=[Parameter("roi", value=True)]
                                 + size_params[:0])
            calls = (("mask", node.sub_mask), ("info_l", node.sub_info_left), ("info_r", node.sub_info_right),
                     ("left", node.sub_left), ("right", node.sub_right))
            matcher_cpu[0] = 0.0
            r = _time_calls(node, frames, calls, repeat, "disparities_published", matcher_cpu=matcher_cpu)
            r["take"] = take_ms(frames, [t for t, s in calls if not s.raw])
            results["disparity_node"] = r
            node.destroy_node()
        finally:
            disparity_module.compute_disparity, disparity_module.disparity_in_window = originals
    finally:
        rclpy.shutdown(context=context)
    load = os.getloadavg()[0]
    print(f"{size}, {n} frames x {repeat}, load average {load:.2f} (CPU ms per frame)")
    for name, r in results.items():
        extra = f", matcher {r['matcher']:.2f} (not counted)" if "matcher" in r else ""
        print(f"  {name:17s} callbacks {r['callbacks']:6.2f}  take {r['take']:5.2f}  "
              f"outputs {r['outputs']}{extra}")


_ROUND = [0]  # rounds so far (stamps only go forward, across nodes too)


def _time_calls(node, frames, calls, repeat, counter, matcher_cpu=None) -> dict:
    """Stamps are shifted per repeat so every round is new to the synchronizers."""
    from rclpy.serialization import serialize_message

    from canopy_stereo.ros.convert import ns_to_stamp

    def restamp(msg, stamp):
        msg.header.stamp = ns_to_stamp(stamp)
        if hasattr(msg, "image"):
            msg.image.header.stamp = msg.header.stamp

    before = node.counts[counter]
    total = 0.0
    node_round = _ROUND
    span = (len(frames) + 1) * 33_333_333
    # one warm round, not timed
    for r in range(repeat + 1):
        for i, fr in enumerate(frames):
            for topic, _ in calls:
                restamp(fr[topic], node_round[0] * span + (i + 1) * 33_333_333)
        node_round[0] += 1
        # a raw subscription (the node reads views of the serialized message) gets the bytes
        inputs = [[serialize_message(fr[topic]) if getattr(sub, "raw", False) else fr[topic]
                   for topic, sub in calls] for fr in frames]
        t0 = time.process_time()
        for row in inputs:
            for (_, sub), msg in zip(calls, row):
                sub.callback(msg)
            if matcher_cpu is not None:  # the matcher runs on the node's worker: wait for it
                deadline = time.monotonic() + 2
                target = node.counts[counter] + 1
                while node.counts[counter] < target and time.monotonic() < deadline:
                    time.sleep(0.0005)
        dt = time.process_time() - t0
        if r == 0:
            warm_outputs = node.counts[counter]
            if matcher_cpu is not None:
                matcher_cpu[0] = 0.0
            continue
        total += dt
    outputs = node.counts[counter] - max(before, warm_outputs)
    out = {"outputs": outputs, "callbacks": total * 1e3 / max(1, outputs)}
    if matcher_cpu is not None:
        out["matcher"] = matcher_cpu[0] * 1e3 / max(1, outputs)
        out["callbacks"] -= out["matcher"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="1280x720", help="frame size (bench_graph's sizes)")
    ap.add_argument("--frames", type=int, default=20, help="distinct frames")
    ap.add_argument("--repeat", type=int, default=3, help="timed rounds over the frames")
    ap.add_argument("--cache", help="file keeping the built messages between runs")
    args = ap.parse_args(argv)
    bench(args.size, args.frames, args.repeat, args.cache)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
