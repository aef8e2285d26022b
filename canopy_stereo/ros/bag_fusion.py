"""A recording's clouds placed by the recording's TF: what ``canopy-stereo fuse --bag`` fuses.

A robot records ``points2`` (the rig's clouds, :mod:`canopy_stereo.ros.nodes.point_cloud`)
with ``/tf`` (the arm or vehicle moving) and ``/tf_static`` (the rig's mount and frames).
:func:`posed_clouds` reads them all, fills a
:class:`~canopy_stereo.geometry.tf_buffer.TransformBuffer` with every transform of the
recording, and looks each cloud's pose ``T_fixed_frame<-cloud frame`` up at the cloud's
stamp (interpolated, as ``fusion_node`` does live). A cloud without a transform is skipped
with tf's reason (unknown frame, not connected, extrapolation). No rclpy node: the messages
are decoded from the recording.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.bag import BagReader
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.tf_buffer import TransformBuffer, TransformLookupError
from canopy_stereo.ros.convert import cloud2_to_points, stamp_to_ns
from canopy_stereo.ros.tf import TF_MESSAGE_TYPE, TF_STATIC_TOPIC, parse_tf_message

#: Type of the clouds read.
CLOUD_TYPE = "sensor_msgs/msg/PointCloud2"


@dataclass
class PosedClouds:
    """Clouds of a recording with their poses.

    Attributes:
        clouds: ``(stamp_ns, points (N, 3) float64 metres in the cloud's frame, colours (N, 3)
            uint8 or None, T_fixed_cloud (4, 4))`` per cloud that found its transform.
        skipped: one line per cloud that did not (its stamp and tf's reason).
        topic: the cloud topic read; frames: the clouds' frame ids.
    """

    clouds: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    topic: str = ""
    frames: set = field(default_factory=set)


def _cloud_topic(bag, topic: str | None) -> str:
    clouds = sorted(t for t, info in bag.topics.items() if info.type_name == CLOUD_TYPE)
    if topic:
        if topic not in bag.topics:
            raise CanopyStereoError(f"{bag.path} has no topic {topic} (clouds: {', '.join(clouds) or 'none'})")
        return topic
    points2 = [t for t in clouds if t.endswith("/points2")]
    if len(points2) != 1:
        raise CanopyStereoError(f"{bag.path}: name the cloud topic with --cloud-topic (PointCloud2 topics: "
                                f"{', '.join(clouds) or 'none'})")
    return points2[0]


def posed_clouds(bag_path, *, fixed_frame: str, cloud_topic: str | None = None) -> PosedClouds:
    """The recording's clouds with their poses in ``fixed_frame`` from its ``/tf`` + ``/tf_static``.

    Args:
        bag_path: a recording (MCAP) with clouds and transforms.
        fixed_frame: the frame to fuse in (e.g. ``base_link``, ``odom``, ``map``).
        cloud_topic: the PointCloud2 topic (default: the recording's one ``.../points2``).

    Raises :class:`CanopyStereoError` (one line) when the recording has no transforms or no
    unambiguous cloud topic.
    """
    bag = BagReader(bag_path)
    topic = _cloud_topic(bag, cloud_topic)
    tf_topics = [t for t, info in bag.topics.items() if info.type_name == TF_MESSAGE_TYPE]
    if not tf_topics:
        raise CanopyStereoError(f"{bag.path} holds no /tf or /tf_static: record them with the clouds "
                                "(or give poses with --poses)")
    stamps = [m.log_time_ns for m in bag.messages(tf_topics)]
    span_s = (max(stamps) - min(stamps)) / 1e9 if stamps else 0.0
    buffer = TransformBuffer(cache_s=span_s + 3600.0)  # the whole recording is history
    for m in bag.messages(tf_topics):
        static = m.topic == TF_STATIC_TOPIC
        for stamp, parent, child, T in parse_tf_message(m.data):
            try:
                buffer.set_transform(parent.lstrip("/"), child.lstrip("/"), T, stamp, static=static)
            except CanopyStereoError:
                continue  # a malformed transform is not kept (as live)
    out = PosedClouds(topic=topic)
    for _, msg in bag.read([topic]):
        stamp, frame = stamp_to_ns(msg.header.stamp), msg.header.frame_id.lstrip("/")
        out.frames.add(frame)
        try:
            T = buffer.lookup(fixed_frame, frame, stamp_ns=stamp)
        except TransformLookupError as exc:
            out.skipped.append(f"cloud at {stamp / 1e9:.6f} s: {exc}")
            continue
        points, colours = cloud2_to_points(msg)
        points = np.asarray(points, np.float64)
        ok = np.all(np.isfinite(points), axis=1)
        out.clouds.append((stamp, points[ok], None if colours is None else colours[ok], T))
    return out
