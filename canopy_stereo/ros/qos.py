"""Quality-of-service profiles used by the nodes.

* Subscriptions: reliable, keep last :data:`INPUT_DEPTH` (5), volatile. REP 2003
  asks consumers of sensor data for sensor-data QoS (best effort), but Fast DDS
  (the Jazzy default) between processes loses most samples larger than its 64 kB
  fragment size when the reader is best effort: measured on this machine with a
  reliable 640x480 bgr8 publisher at 15 Hz, a best-effort subscriber in another
  process received 4 of 30 images (0 of 10 at 2 Hz), a reliable one 30 of 30 (see
  ros2/rmw_fastrtps#739). Keep-last makes the newest frames win when a node falls
  far behind (the disparity node, the slowest stage, also keeps at most 2 complete
  pairs waiting for the matcher: latency stays bounded); a reliable subscription matches the
  system-default (reliable) publishers of camera drivers, and not best-effort
  ones: override it per topic with ``qos_overrides.<topic>.subscription.reliability``.
  Compressed images are the exception: a JPEG frame (30-160 kB at 640x480) crosses
  processes best effort without loss (measured: 90 of 90 croton frames of 155 kB at
  30 Hz, reliable or best-effort publisher, against 22 of 90 raw 0.9 MB frames;
  ``benchmarks/bench_transport_qos.py``), so ``rectify_node`` reads
  ``<side>/image_raw/compressed`` with REP 2003's sensor-data QoS, which also matches
  drivers publishing best effort (:func:`sensor_data_qos`).
* Publishers: reliable, keep last :data:`OUTPUT_DEPTH` (5), volatile, as REP 2003
  asks of sensor publishers (system-default QoS); they serve reliable and
  best-effort subscribers. The node parameter ``reliability: best_effort``
  switches them to best effort (lossy links).
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

#: Keep-last depth of the nodes' subscriptions.
INPUT_DEPTH = 5

#: Keep-last depth of the nodes' publishers.
OUTPUT_DEPTH = 5


def subscription_qos(depth: int | None = None) -> QoSProfile:
    """Reliable keep-last QoS for the nodes' inputs (``depth`` overrides :data:`INPUT_DEPTH`)."""
    return QoSProfile(history=HistoryPolicy.KEEP_LAST,
                      depth=int(INPUT_DEPTH if depth is None else depth),
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


def sensor_data_qos(depth: int | None = None) -> QoSProfile:
    """rclpy's sensor-data QoS (best effort, keep last 5, volatile), e.g. for a foreign
    consumer that follows REP 2003 (``depth`` overrides the keep-last depth)."""
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
