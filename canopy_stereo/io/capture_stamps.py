"""Stamps of captured frames: the driver's capture time on the ROS clock, latency and jitter.

A frame stamped when ``read()`` returns carries the USB transfer and the decode (jitter of
milliseconds, tenths of a second seen with usb_cam). V4L2 stamps each buffer when the
device starts filling it, on ``CLOCK_MONOTONIC`` (``V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC``);
OpenCV's V4L2 backend exposes it as ``CAP_PROP_POS_MSEC``. :class:`CaptureClock` maps
that instant onto the ROS clock by the offset between the two clocks read together when
the frame is received::

    stamp = ros_now - (monotonic_now - capture_monotonic)

and checks that the driver's time really is a monotonic capture time (not a video file's
position): it must lie before the reception and less than :data:`MAX_DRIVER_LATENCY_S`
earlier. Otherwise the frame is stamped ``ros_now - latency_s``, the configured latency
(``camera_node``'s ``stamp_latency``).

It also measures, over the last :data:`WINDOW` frames, the *latency* (reception minus
capture, ms; only known with driver times) and the *jitter* (standard deviation of the
stamp intervals around their median, ms), which ``camera_node`` reports on ``/diagnostics``.
Units: nanoseconds in, nanoseconds out; milliseconds in the statistics.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Longest plausible time (s) between a capture and its reception.
MAX_DRIVER_LATENCY_S = 2.0

#: Frames the latency and jitter are measured over.
WINDOW = 60

#: Values of :attr:`CapturedStamp.source`.
SOURCES = ("driver", "receive")


@dataclass(frozen=True)
class CapturedStamp:
    """A frame's stamp (ROS clock, ns), where it came from and its measured latency (ms or None)."""

    stamp_ns: int
    source: str
    latency_ms: float | None


class CaptureClock:
    """Stamp frames from the driver's capture time when it has one (see module docstring).

    Args:
        latency_s: seconds subtracted from the reception time when the driver gives no
            usable capture time (>= 0).
    """

    def __init__(self, *, latency_s: float = 0.0):
        if not latency_s >= 0:
            raise CanopyStereoError(f"stamp latency must be >= 0 s, got {latency_s}")
        self.latency_ns = int(round(latency_s * 1e9))
        self._latencies: deque[float] = deque(maxlen=WINDOW)
        self._stamps: deque[int] = deque(maxlen=WINDOW + 1)

    def stamp(self, *, receive_ns: int, receive_monotonic_ns: int,
              driver_monotonic_ns: int | None = None) -> CapturedStamp:
        """The stamp of a frame received at ``receive_ns`` (ROS clock) =
        ``receive_monotonic_ns`` (``CLOCK_MONOTONIC``), captured at ``driver_monotonic_ns``
        by the driver's clock (None or <= 0: unknown)."""
        latency = None
        if driver_monotonic_ns is not None and driver_monotonic_ns > 0:
            age = receive_monotonic_ns - driver_monotonic_ns
            if 0 <= age <= MAX_DRIVER_LATENCY_S * 1e9:
                latency = age
        if latency is None:
            out = CapturedStamp(int(receive_ns) - self.latency_ns, "receive", None)
        else:
            self._latencies.append(latency / 1e6)
            out = CapturedStamp(int(receive_ns) - int(latency), "driver", latency / 1e6)
        self._stamps.append(out.stamp_ns)
        return out

    @property
    def latency_ms(self) -> float | None:
        """Median measured capture -> reception latency over the window (ms), or None."""
        return float(np.median(self._latencies)) if self._latencies else None

    @property
    def jitter_ms(self) -> float | None:
        """Standard deviation of the stamp intervals around their median over the window
        (ms), or None before three frames."""
        if len(self._stamps) < 3:
            return None
        intervals = np.diff(np.asarray(self._stamps, dtype=np.int64)).astype(np.float64) / 1e6
        return float(np.sqrt(np.mean((intervals - np.median(intervals)) ** 2)))
