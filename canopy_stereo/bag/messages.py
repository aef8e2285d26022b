"""What a bag holds: serialized messages, topics and their QoS metadata.

A message is stored as CDR bytes (``rclpy.serialization``'s, with the encapsulation
header); :meth:`BagMessage.decode` turns it back into the ROS message (rclpy is imported
only then). Times are integer nanoseconds since the epoch.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import yaml

from canopy_stereo.bag.errors import BagError, _one_line
from canopy_stereo.bag.msgdefs import deserialize, message_class
from canopy_stereo.errors import CanopyStereoError

_INFINITE = {"sec": 9223372036, "nsec": 854775807}


def qos_profiles_yaml(reliability: str = "reliable", depth: int = 1,
                      *, durability: str = "volatile") -> str:
    """``offered_qos_profiles`` metadata (rosbag2 v9 YAML) for one publisher."""
    profile = {
        "history": "keep_last", "depth": int(depth), "reliability": reliability,
        "durability": durability, "deadline": dict(_INFINITE), "lifespan": dict(_INFINITE),
        "liveliness": "automatic", "liveliness_lease_duration": dict(_INFINITE),
        "avoid_ros_namespace_conventions": False,
    }
    return yaml.safe_dump([profile], sort_keys=False)


class BagMessage(NamedTuple):
    """One serialized message of a bag.

    Attributes:
        topic, type_name: e.g. ``/stereo/left/image_raw``, ``sensor_msgs/msg/Image``.
        log_time_ns: reception time (ns since the epoch); playback timing uses it.
        publish_time_ns: header stamp, or the log time.
        data: CDR bytes (with encapsulation header).
    """

    topic: str
    type_name: str
    log_time_ns: int
    publish_time_ns: int
    data: bytes

    def decode(self):
        """The deserialized ROS message; :class:`BagError` when the bytes are not valid CDR
        of the topic's type."""
        try:
            cls = message_class(self.type_name)
        except CanopyStereoError as exc:
            raise BagError(f"topic {self.topic}: {exc}") from None
        try:
            return deserialize(self.data, cls)
        except Exception as exc:  # noqa: BLE001 - rclpy raises various types for bad CDR
            raise BagError(f"topic {self.topic}: message at log time {self.log_time_ns} ns is not "
                           f"valid {self.type_name} CDR ({len(self.data)} bytes: "
                           f"{type(exc).__name__}: {_one_line(exc)})") from None


@dataclass
class TopicInfo:
    """A topic of a bag: type, number of messages, definition and QoS metadata."""

    name: str
    type_name: str
    message_count: int = 0
    definition: str = ""
    qos_yaml: str = ""


def _stamp_of(msg) -> int | None:
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _normal_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS 1 style names in foreign schemas)."""
    return name if name.count("/") == 2 else name.replace("/", "/msg/", 1)
