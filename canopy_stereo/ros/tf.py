"""Static transforms (REP 105 ``/tf_static``) of the rig: live and in bags.

* Live: :class:`StaticTransformPublisher` publishes ``tf2_msgs/TFMessage`` on
  ``/tf_static`` (reliable, transient local, keep last 1, as tf2_ros's
  ``StaticTransformBroadcaster``) when the ``tf2_msgs`` Python package is importable
  (any ROS install; it is not on PyPI).
* Bags: :func:`write_static_transforms` writes the same message into a
  :class:`~canopy_stereo.bag.BagWriter` *always*, serialized here (CDR) with the
  ``tf2_msgs/msg/TFMessage`` definition, so RViz, Foxglove and Rerun replaying the
  bag see the frames whether or not ``tf2_msgs`` is installed.

The transforms themselves come from :func:`canopy_stereo.geometry.frames.stereo_transforms`.
"""
from __future__ import annotations

import struct

import numpy as np
from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from canopy_stereo.geometry.frames import quaternion_to_rotation, rotation_to_quaternion
from canopy_stereo.ros.convert import make_header, stamp_to_ns

TF_STATIC_TOPIC = "/tf_static"
TF_MESSAGE_TYPE = "tf2_msgs/msg/TFMessage"


def latched_qos() -> QoSProfile:
    """Reliable, transient local, keep last 1: late subscribers get the last message."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def tf_message_class():
    """``tf2_msgs.msg.TFMessage``, or None when tf2_msgs is not installed."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


def transform_msg(parent: str, child: str, T, *, stamp_ns: int = 0) -> TransformStamped:
    """``geometry_msgs/TransformStamped`` of ``T_parent_child`` (4x4, metres)."""
    T = np.asarray(T, np.float64)
    msg = TransformStamped()
    msg.header = make_header(stamp_ns, parent)
    msg.child_frame_id = child
    x, y, z = (float(v) for v in T[:3, 3])
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = x, y, z
    q = rotation_to_quaternion(T[:3, :3])
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = (float(v) for v in q)
    return msg


def msg_to_transform(msg) -> tuple[str, str, np.ndarray]:
    """``(parent, child, T_parent_child)`` of a TransformStamped (any object with its fields)."""
    t, q = msg.transform.translation, msg.transform.rotation
    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation([q.x, q.y, q.z, q.w])
    T[:3, 3] = [t.x, t.y, t.z]
    return msg.header.frame_id, msg.child_frame_id, T


def transforms_to_msgs(transforms, stamp_ns: int = 0) -> list[TransformStamped]:
    """TransformStamped messages of ``[(parent, child, T), ...]``."""
    return [transform_msg(p, c, T, stamp_ns=stamp_ns) for p, c, T in transforms]


def tf_message_definition() -> str:
    """``ros2msg`` schema text of ``tf2_msgs/msg/TFMessage`` with its nested types."""
    from canopy_stereo.bag.msgdefs import message_definition

    sep = "=" * 80
    return (f"geometry_msgs/TransformStamped[] transforms\n{sep}\nMSG: geometry_msgs/TransformStamped\n"
            + message_definition("geometry_msgs/msg/TransformStamped"))


class _Cdr:
    """Little-endian CDR writer (alignment relative to the payload, after the 4-byte header)."""

    def __init__(self):
        self.buf = bytearray()

    def _align(self, n: int) -> None:
        self.buf += b"\0" * ((-len(self.buf)) % n)

    def put(self, fmt: str, *values) -> None:
        size = struct.calcsize("<" + fmt[0])
        self._align(size)
        self.buf += struct.pack("<" + fmt, *values)

    def string(self, s: str) -> None:
        data = s.encode("utf-8") + b"\0"
        self.put("I", len(data))
        self.buf += data


def serialize_tf_message(transforms: list[TransformStamped]) -> bytes:
    """CDR bytes of a ``tf2_msgs/msg/TFMessage`` (what rclpy would publish), built without
    the tf2_msgs package."""
    w = _Cdr()
    w.put("I", len(transforms))
    for m in transforms:
        w.put("i", int(m.header.stamp.sec))
        w.put("I", int(m.header.stamp.nanosec))
        w.string(m.header.frame_id)
        w.string(m.child_frame_id)
        t, q = m.transform.translation, m.transform.rotation
        w.put("ddd", t.x, t.y, t.z)
        w.put("dddd", q.x, q.y, q.z, q.w)
    return b"\x00\x01\x00\x00" + bytes(w.buf)


def parse_tf_message(data: bytes) -> list[tuple[int, str, str, np.ndarray]]:
    """``[(stamp_ns, parent, child, T_parent_child), ...]`` of a CDR ``tf2_msgs/msg/TFMessage``
    (a recording's ``/tf`` or ``/tf_static``), read without the tf2_msgs package. Raises
    :class:`~canopy_stereo.errors.CanopyStereoError` on bytes that are not such a message."""
    from canopy_stereo.errors import CanopyStereoError

    buf = bytes(data)
    if len(buf) < 8 or buf[0] != 0 or buf[1] not in (0, 1):
        raise CanopyStereoError("TFMessage is not CDR (bad encapsulation header)")
    order = "<" if buf[1] == 1 else ">"
    pos = 4

    def take(fmt: str):
        nonlocal pos
        size = struct.calcsize(order + fmt[0])
        pos += (-(pos - 4)) % size
        end = pos + struct.calcsize(order + fmt)
        if end > len(buf):
            raise CanopyStereoError(f"TFMessage is cut short ({len(buf)} bytes)")
        values = struct.unpack(order + fmt, buf[pos:end])
        pos = end
        return values

    def string() -> str:
        nonlocal pos
        (n,) = take("I")
        if n < 1 or pos + n > len(buf):
            raise CanopyStereoError("TFMessage holds a malformed string")
        text = buf[pos:pos + n - 1].decode("utf-8", errors="replace")
        pos += n
        return text

    (count,) = take("I")
    if count > len(buf) // 64:
        raise CanopyStereoError(f"TFMessage claims {count} transforms in {len(buf)} bytes")
    out = []
    for _ in range(count):
        sec, nsec = take("iI")
        parent, child = string(), string()
        x, y, z, qx, qy, qz, qw = take("ddddddd")
        T = np.eye(4)
        T[:3, :3] = quaternion_to_rotation([qx, qy, qz, qw])
        T[:3, 3] = [x, y, z]
        out.append((sec * 1_000_000_000 + nsec, parent, child, T))
    return out


def write_static_transforms(writer, transforms, log_time_ns: int, *, topic: str = TF_STATIC_TOPIC) -> None:
    """Write ``[(parent, child, T), ...]`` (or TransformStamped messages) as one
    ``tf2_msgs/msg/TFMessage`` on ``/tf_static`` into a :class:`BagWriter`, with the
    transient-local QoS a ``ros2 bag play`` needs to re-publish it as latched."""
    from canopy_stereo.bag.messages import qos_profiles_yaml

    msgs = [m if isinstance(m, TransformStamped) else transform_msg(*m, stamp_ns=log_time_ns)
            for m in transforms]
    writer.add_topic(topic, TF_MESSAGE_TYPE, qos_yaml=qos_profiles_yaml("reliable", 1,
                                                                        durability="transient_local"),
                     definition=tf_message_definition())
    stamp = stamp_to_ns(msgs[0].header.stamp) if msgs else log_time_ns
    writer.write(topic, serialize_tf_message(msgs), log_time_ns, publish_time_ns=stamp,
                 msg_type=TF_MESSAGE_TYPE)


class StaticTransformPublisher:
    """Publish transforms once on ``/tf_static`` (latched) when tf2_msgs is importable (none
    when ``transforms`` is empty).

    Attributes:
        available: True when tf2_msgs was found and the transforms were published.
    """

    def __init__(self, node, transforms, stamp_ns: int | None = None):
        cls = tf_message_class()
        self.available = cls is not None
        self.publisher = None
        if not self.available or not transforms:
            return
        stamp = node.get_clock().now().nanoseconds if stamp_ns is None else int(stamp_ns)
        self.publisher = node.create_publisher(cls, TF_STATIC_TOPIC, latched_qos())
        self.publisher.publish(cls(transforms=transforms_to_msgs(transforms, stamp)))
