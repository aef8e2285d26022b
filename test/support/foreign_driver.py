"""A stand-in for a camera driver that is not ours (usb_cam, v4l2_camera, ...): plain rclpy on
Fast DDS's defaults (it never loads canopy_stereo's DDS profile or settings: start it with an
environment without ``FASTRTPS_DEFAULT_PROFILES_FILE``/``RMW_FASTRTPS_USE_QOS_FROM_XML``, see
:func:`foreign_env`), system-default QoS (reliable, keep last 10), publishing bgr8 pairs on
``/stereo/left|right/image_raw`` stamped with the wall clock at publication, as drivers do.

    python -m test.support.foreign_driver --rate 10 --frames 200 [--scene croton|plants|aloe]

Waits until both topics have ``--subscribers`` subscriptions (default 1), sends, waits
``--linger`` s and prints one JSON line ``{"sent": {stamp_ns: monotonic s}, ...}``
(``time.monotonic`` is CLOCK_MONOTONIC, comparable across processes on Linux).
"""
from __future__ import annotations

import argparse
import json
import sys
import time

#: Environment variables by which a process would load canopy_stereo's (or any) Fast DDS settings.
DDS_SETTINGS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE", "RMW_FASTRTPS_USE_QOS_FROM_XML",
                "SKIP_DEFAULT_XML", "FASTDDS_BUILTIN_TRANSPORTS", "RMW_FASTRTPS_PUBLICATION_MODE")


def foreign_env(env: dict) -> dict:
    """``env`` without any Fast DDS settings (a foreign driver's environment)."""
    return {k: v for k, v in env.items() if k not in DDS_SETTINGS}


def load_frames(scene: str = "croton"):
    """(left, right) bgr8 640x480 pairs of a bundled bag, or of the Aloe (``aloe``: the shared data's,
    :mod:`test.support.aloe`)."""
    if scene == "aloe":
        from test.support.aloe import ALOE_CROP, aloe_source

        _, left, right = aloe_source()
        (x, y) = ALOE_CROP
        return [(left[y:y + 480, x:x + 640].copy(), right[y:y + 480, x:x + 640].copy())]
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.bundled import bundled_bag
    from canopy_stereo.ros.convert import msg_to_image

    bag = BagReader(bundled_bag(scene))
    lefts = [msg_to_image(m).copy() for _, m in bag.read("/stereo/left/image_raw")]
    rights = [msg_to_image(m).copy() for _, m in bag.read("/stereo/right/image_raw")]
    if scene == "plants":  # 710x496: the 640x480 crop the benchmarks use
        lefts = [img[8:488, 35:675].copy() for img in lefts]
        rights = [img[8:488, 35:675].copy() for img in rights]
    return list(zip(lefts, rights))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=10.0)
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--scene", default="croton")
    p.add_argument("--subscribers", type=int, default=1)
    p.add_argument("--wait", type=float, default=120.0, help="seconds to wait for the subscribers")
    p.add_argument("--linger", type=float, default=3.0, help="seconds to keep the writers after the last pair")
    opts = p.parse_args(argv)
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from canopy_stereo.ros.convert import image_to_msg

    frames = load_frames(opts.scene)
    rclpy.init(args=[])
    node = rclpy.create_node("foreign_camera_driver", namespace="/stereo")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)  # rclpy's system default
    pubs = node.create_publisher(Image, "left/image_raw", qos), node.create_publisher(Image, "right/image_raw", qos)
    deadline = time.monotonic() + opts.wait
    while any(p.get_subscription_count() < opts.subscribers for p in pubs):
        if time.monotonic() > deadline:
            print(json.dumps({"error": "no subscribers"}))
            return 1
        time.sleep(0.05)
    time.sleep(0.5)
    msgs = [(image_to_msg(left, "bgr8", frame_id="left_camera_optical_frame"),
             image_to_msg(right, "bgr8", frame_id="right_camera_optical_frame")) for left, right in frames]
    sent = {}
    t0 = time.monotonic()
    for k in range(opts.frames):
        delay = t0 + k / opts.rate - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        left, right = msgs[k % len(msgs)]
        stamp = time.time_ns()
        for msg in (left, right):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            pubs[msg is right].publish(msg)
        sent[stamp] = time.monotonic()
    time.sleep(opts.linger)
    print(json.dumps({"sent": sent, "wall_s": time.monotonic() - t0}), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
