"""Benchmark: rectify_node's CPU per pair (issue 28, item 3), offline, without the graph.

One ``RectifyNode`` in this process is handed ``--pairs`` pairs of bench_graph's frames
(the drifting Plants window at ``--size``, fresh noise per frame, the right image 4 ms after
the left: the default skew compensation works on every pair) straight into its input callback,
as its executor would after taking them (one pair at a time: the node's worker rectifies
and publishes each before the next comes): raw bgr8 ``Image`` messages or, with
``--transport compressed``, JPEG ``CompressedImage`` (quality 95). A helper node subscribes to
the three rectified images (raw subscriptions, never taken), so every output is published as in
the graph. Prints the process's CPU per pair (conversion, pairing, rectification, skew
compensation, messages, publishing, Fast DDS's threads), the median over ``--repeats`` runs.

``--maps``: ``bench`` (default: bench_graph's rig of the frames; the Plants pair is rectified
already, so its rectification maps are the identity and the images are not resampled) or
``paper`` (config/paper_rig.yaml, a rig with rotated cameras and lens distortion, scaled to the
size: the remaps of a real webcam pair, on the same frames).

    .venv/bin/python benchmarks/bench_rectify.py --size 1280x720
    .venv/bin/python benchmarks/bench_rectify.py --size 640x480 --transport compressed
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

PERIOD_NS, SKEW_NS = 33_333_333, 4_000_000


def run(size: str, transport: str, n_pairs: int, repeats: int, maps: str) -> None:
    from bench_graph import bench_frames
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from canopy_stereo.ros.compressed import image_to_compressed_msg
    from canopy_stereo.ros.context import ros_context, tune_opencv_threads, wait_for
    from canopy_stereo.ros.convert import image_to_msg
    from canopy_stereo.ros.nodes.rectify import RectifyNode
    from canopy_stereo.ros.params import rig_parameter_overrides

    tune_opencv_threads()  # as in a node process: one OpenCV thread
    rig, frames = bench_frames("plants", size, n_frames=30)
    if maps == "paper":
        from bench_graph import scaled_rig

        from canopy_stereo.io.rig import load_rig

        paper = load_rig(Path(__file__).resolve().parents[1] / "config" / "paper_rig.yaml")
        width, height = rig.image_size
        scale = width / paper.image_size[0]
        window = (round(width / scale), round(height / scale))
        rig = scaled_rig(paper, scale, (0, (paper.image_size[1] - window[1]) // 2), window)
    if transport == "compressed":
        msgs = [(image_to_compressed_msg(left, quality=95), image_to_compressed_msg(right, quality=95))
                for left, right in frames]
    else:
        msgs = [(image_to_msg(left, "bgr8"), image_to_msg(right, "bgr8")) for left, right in frames]
    with ros_context() as ctx:
        import rclpy.node

        node = RectifyNode(context=ctx, namespace="/stereo", start_parameter_services=False,
                           parameter_overrides=rig_parameter_overrides(rig) + [
                               Parameter("image_transport", value=transport), Parameter("fps", value=30.0)])
        probe = rclpy.node.Node("bench_probe", context=ctx, namespace="/stereo", start_parameter_services=False)
        qos = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
        subs = [probe.create_subscription(Image, topic, lambda _m: None, qos, raw=True)
                for topic in ("left/image_rect", "right/image_rect", "left/image_rect_color")]
        wait_for(lambda: all(s.get_publisher_count() >= 1 for s in subs), 20.0)
        k = 0

        def published() -> int:
            return node.stats()["counts"].get("pairs_published", 0)

        def feed(n: int) -> float:
            nonlocal k
            t_proc = time.process_time()
            for _ in range(n):
                left, right = msgs[k % len(msgs)]
                stamp = 1_700_000_000_000_000_000 + k * PERIOD_NS
                done = published()
                for side, msg, t in ((0, left, stamp), (1, right, stamp + SKEW_NS)):
                    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
                    node._on_image(side, msg)
                while published() == done:  # the node's worker rectifies and publishes the pair
                    time.sleep(0.002)
                k += 1
            return 1e3 * (time.process_time() - t_proc) / n

        feed(10)  # warm-up
        runs = [feed(n_pairs) for _ in range(repeats)]
        n_published = published()
        compensated = node.stats()["counts"].get("pairs_skew_compensated", 0)
        node.destroy_node()
        probe.destroy_node()
    print(f"rectify_node {size} {transport} ({maps} maps): {statistics.median(runs):.1f} ms CPU per pair "
          f"(runs {', '.join(f'{r:.1f}' for r in runs)}); {n_published} pairs published, "
          f"{compensated} skew-compensated")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--size", default="1280x720", choices=("640x480", "1280x720", "1280x960"))
    p.add_argument("--transport", default="raw", choices=("raw", "compressed"))
    p.add_argument("--pairs", type=int, default=60, help="pairs per run (default 60)")
    p.add_argument("--repeats", type=int, default=3, help="runs; the median is printed (default 3)")
    p.add_argument("--maps", default="bench", choices=("bench", "paper"),
                   help="rectification maps: bench (identity, the frames' rig) or paper (rotated, distorted)")
    args = p.parse_args(argv)
    run(args.size, args.transport, args.pairs, args.repeats, args.maps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
