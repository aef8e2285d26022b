"""Quality-of-service profiles used by the nodes.

* Subscriptions: sensor-data QoS (best effort, keep last 5, volatile), which
  accepts both reliable and best-effort publishers and never blocks them.
* Publishers: reliable, keep last 1, volatile; the node parameter
  ``reliability: best_effort`` switches them to best effort (lossy links).
* Recording: keep last ``depth``, reliable where the publishers are (a recorder
  must not miss outputs).
"""
from __future__ import annotations

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from canopy_stereo.errors import CanopyStereoError

RELIABILITY_CHOICES = ("reliable", "best_effort")


def subscription_qos(depth: int | None = None) -> QoSProfile:
    """Sensor-data QoS for the nodes' inputs (a new profile; ``depth`` overrides keep-last 5)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST,
                      depth=int(qos_profile_sensor_data.depth if depth is None else depth),
                      reliability=qos_profile_sensor_data.reliability,
                      durability=qos_profile_sensor_data.durability)


def publisher_qos(reliability: str = "reliable", depth: int = 1) -> QoSProfile:
    """Publisher QoS: ``reliability`` is ``"reliable"`` or ``"best_effort"``."""
    policies = {"reliable": ReliabilityPolicy.RELIABLE, "best_effort": ReliabilityPolicy.BEST_EFFORT}
    if reliability not in policies:
        raise CanopyStereoError(f"reliability must be one of {', '.join(RELIABILITY_CHOICES)}, "
                                f"got {reliability!r}")
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(depth),
                      reliability=policies[reliability], durability=DurabilityPolicy.VOLATILE)


def recording_qos(depth: int = 50, reliability: str = "reliable") -> QoSProfile:
    """Subscription with a deep queue, for recorders and test sinks.

    Use ``"reliable"`` unless a publisher of the topic is best effort (a reliable
    subscription does not match a best-effort publisher).
    """
    return publisher_qos(reliability, depth)
