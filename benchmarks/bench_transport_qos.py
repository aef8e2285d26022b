"""Does sensor-data (best-effort) QoS deliver camera images between processes on Fast DDS?

REP 2003 asks image consumers for sensor-data QoS (best effort). Fast DDS drops most
best-effort samples larger than its 64 kB fragment when they cross processes (the reason the
nodes' raw-image inputs are reliable, :mod:`canopy_stereo.ros.qos`). A compressed 640x480
frame is 30-120 kB. This measures it: a publisher *process* (reliable, keep last 10, as
image_transport's default, or best effort as drivers using SensorDataQoS) sends N croton
frames at R Hz as bgr8 ``Image`` and as JPEG ``CompressedImage`` at several qualities; this
process subscribes with reliable and with sensor-data QoS and counts what arrives.

``python benchmarks/bench_transport_qos.py [--frames 90] [--rate 30]``
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

PUBLISHER = r"""
import sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image
from canopy_stereo.ros.compressed import image_to_compressed_msg
from canopy_stereo.ros.convert import image_to_msg
from test.support.ros_harness import croton_frames

kind, quality, reliability, n, rate = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), float(sys.argv[5])
rclpy.init()
node = rclpy.create_node("qos_bench_pub")
qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE if reliability == "reliable"
                 else ReliabilityPolicy.BEST_EFFORT)
frames = [l for l, _ in croton_frames()]
if kind == "raw":
    pub = node.create_publisher(Image, "/bench/image", qos)
    msgs = [image_to_msg(f, "bgr8") for f in frames]
else:
    pub = node.create_publisher(CompressedImage, "/bench/image", qos)
    msgs = [image_to_compressed_msg(f, quality=quality) for f in frames]
print("size", len(msgs[0].data), flush=True)
deadline = time.monotonic() + 30
while pub.get_subscription_count() < 2 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(1.0)
t0 = time.monotonic()
for k in range(n):
    time.sleep(max(0.0, t0 + k / rate - time.monotonic()))
    m = msgs[k % len(msgs)]
    m.header.stamp.sec, m.header.stamp.nanosec = 1, k
    pub.publish(m)
time.sleep(1.0)
node.destroy_node()
rclpy.shutdown()
"""


def measure(kind: str, quality: int, reliability: str, frames: int, rate: float, domain: int) -> tuple[int, dict]:
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CompressedImage, Image

    from canopy_stereo.ros.qos import sensor_data_qos

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("qos_bench_sub", context=ctx)
    cls = Image if kind == "raw" else CompressedImage
    got = {"reliable": set(), "sensor_data": set()}
    node.create_subscription(cls, "/bench/image", lambda m: got["reliable"].add(m.header.stamp.nanosec),
                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    node.create_subscription(cls, "/bench/image", lambda m: got["sensor_data"].add(m.header.stamp.nanosec),
                             sensor_data_qos())
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    proc = subprocess.Popen([sys.executable, "-c", PUBLISHER, kind, str(quality), reliability, str(frames),
                             str(rate)], env=env, cwd=root, stdout=subprocess.PIPE, text=True)
    size = 0
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    while proc.poll() is None:
        ex.spin_once(timeout_sec=0.05)
    out = proc.stdout.read()
    for line in out.splitlines():
        if line.startswith("size"):
            size = int(line.split()[1])
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    ex.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    return size, {k: len(v) for k, v in got.items()}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=90)
    p.add_argument("--rate", type=float, default=30.0)
    p.add_argument("--cases", default="raw:0:reliable,jpeg:95:reliable,jpeg:80:reliable,jpeg:95:best_effort",
                   help="KIND:QUALITY:PUBLISHER_RELIABILITY,...")
    args = p.parse_args()
    from canopy_stereo.ros.context import private_domain_id

    domain = private_domain_id()
    print(f"{args.frames} frames at {args.rate:g} Hz from another process (machine load: {os.getloadavg()[0]:.1f})")
    print("| message | bytes | publisher | reliable subscriber | sensor-data subscriber |")
    print("|---|---|---|---|---|")
    for case in args.cases.split(","):
        kind, quality, reliability = case.split(":")
        size, got = measure(kind, int(quality), reliability, args.frames, args.rate, domain)
        name = "bgr8 Image" if kind == "raw" else f"JPEG q{quality}"
        rel = "-" if reliability == "best_effort" else f"{got['reliable']}/{args.frames}"
        print(f"| {name} | {size} | {reliability} | {rel} | {got['sensor_data']}/{args.frames} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
