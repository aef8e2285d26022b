"""Per-node diagnostics on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``).

``diagnostic_updater`` is not on PyPI, so this is a small publisher of the same
messages: every :class:`~canopy_stereo.ros.nodes.base.CanopyNode` reports, about
once per second (parameter ``diagnostic_period``), one ``DiagnosticStatus``
named ``"<namespace>/<node name>: pipeline"`` (the fully qualified name without its
leading ``/``, so that two rigs in their own namespaces never share a status name;
``hardware_id`` the node's fully qualified name, or the camera device) with these key/values over the last window:

* ``in <topic> Hz`` / ``out <topic> Hz``: messages received / published per second
  (and ``... total`` since start);
* ``dropped``: inputs dropped in the window, and ``dropped: <reason>`` per reason;
* ``latency median ms`` / ``latency max ms``: from the arrival of the first input
  carrying a stamp to the publication of the output with that stamp (includes
  waiting for a partner frame);
* ``busy %``: share of the window spent in callbacks;
* node-specific statistics, e.g. ``pair offset mean ms`` / ``max ms`` of the
  rectify node (left/right stamp difference of the pairs it made);
* ``time jumps``: stamps that went backwards and reset the node's pairing;
* ``warning: <reason>``: inputs kept but suspicious (a zero stamp restamped with the receive
  time, a stamp far from the receive time: :mod:`canopy_stereo.ros.stamps`).

Level: ERROR when a callback failed with an internal error in the window, WARN
when inputs were dropped, warned about, or stopped arriving (after having arrived),
else OK. ``rqt_robot_monitor``, ``diagnostic_aggregator`` and Foxglove read it as
they read ``diagnostic_updater``'s output.
"""
from __future__ import annotations

import threading
import time
from collections import Counter, OrderedDict

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Topic every node publishes its status on (absolute, as diagnostic_updater does).
DIAGNOSTICS_TOPIC = "/diagnostics"

#: Default seconds between two reports.
DEFAULT_PERIOD_S = 1.0

#: Stamps remembered for the latency measurement (arrival of the first input with a stamp).
_ARRIVALS_KEPT = 256

LEVEL_NAMES = {DiagnosticStatus.OK: "OK", DiagnosticStatus.WARN: "WARN", DiagnosticStatus.ERROR: "ERROR"}


def _fmt(value: float) -> str:
    return f"{value:.3g}" if abs(value) < 1000 else f"{value:.0f}"


class NodeDiagnostics:
    """Rates, drops, latency and statistics of one node, published as a DiagnosticArray.

    Thread-safe: the ``received``/``published``/``dropped``/``sample`` hooks may be
    called from any callback thread. ``period_s <= 0`` keeps the statistics but
    publishes nothing (``status()`` still works).
    """

    def __init__(self, node, period_s: float = DEFAULT_PERIOD_S, hardware_id: str = ""):
        self.node = node
        self.name = f"{node.get_fully_qualified_name().lstrip('/')}: pipeline"
        self.hardware_id = hardware_id or node.get_fully_qualified_name()
        self._lock = threading.Lock()
        self._arrivals: OrderedDict = OrderedDict()
        self._window_start = time.monotonic()
        self._in = Counter()
        self._out = Counter()
        self._in_total = Counter()
        self._out_total = Counter()
        self._drops = Counter()
        self._drops_total = 0
        self._warnings = Counter()
        self._latencies: list[float] = []
        self._samples: dict[str, list[float]] = {}
        self._notes = Counter()
        self._busy_s = 0.0
        self._errors = 0
        self._jumps = 0
        self._last_input = None
        self.pub = self.timer = None
        if period_s > 0:
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                             reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
            self.pub = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, qos)
            self.timer = node.create_timer(float(period_s), self.publish)

    # ------------------------------------------------------------------ hooks
    def received(self, topic: str, stamp_ns: int | None = None) -> None:
        """An input arrived on ``topic`` (stamped ``stamp_ns``, if it has a header)."""
        now = time.monotonic()
        with self._lock:
            self._in[topic] += 1
            self._in_total[topic] += 1
            self._last_input = now
            if stamp_ns is not None and stamp_ns not in self._arrivals:
                self._arrivals[stamp_ns] = now
                while len(self._arrivals) > _ARRIVALS_KEPT:
                    self._arrivals.popitem(last=False)

    def published(self, topic: str, stamp_ns: int | None = None) -> None:
        """An output was published on ``topic``; its latency is measured when an input
        with the same stamp arrived earlier."""
        now = time.monotonic()
        with self._lock:
            self._out[topic] += 1
            self._out_total[topic] += 1
            if stamp_ns is not None:
                t = self._arrivals.get(stamp_ns)
                if t is not None:
                    self._latencies.append(now - t)

    def dropped(self, reason: str, internal: bool = False) -> None:
        """An input was dropped for ``reason`` (``internal``: an unexpected exception)."""
        with self._lock:
            self._drops[reason] += 1
            self._drops_total += 1
            if internal:
                self._errors += 1

    def warned(self, reason: str) -> None:
        """An input was kept but is suspicious for ``reason`` (WARN, without a drop)."""
        with self._lock:
            self._warnings[reason] += 1

    def sample(self, key: str, value: float) -> None:
        """A value of a node-specific statistic (reported as mean and max per window)."""
        with self._lock:
            self._samples.setdefault(key, []).append(float(value))

    def note(self, key: str) -> None:
        """Count one occurrence of an event that is not a drop (reported per window as
        ``key`` with its count), e.g. why a pair went on uncompensated."""
        with self._lock:
            self._notes[key] += 1

    def busy(self, seconds: float) -> None:
        """Time spent in a callback."""
        with self._lock:
            self._busy_s += seconds

    def time_jump(self) -> None:
        """The node's stamps jumped back and its pairing was reset."""
        with self._lock:
            self._jumps += 1

    def restart(self) -> None:
        """Start the window (and the report timer's period) now, e.g. once the node is ready."""
        with self._lock:
            self._window_start = time.monotonic()
        if self.timer is not None:
            self.timer.reset()

    # ------------------------------------------------------------------ report
    def status(self, reset: bool = True) -> DiagnosticStatus:
        """The status over the window since the last report (``reset``: start a new window)."""
        now = time.monotonic()
        with self._lock:
            elapsed = max(1e-6, now - self._window_start)
            values: list[tuple[str, str]] = [("window s", _fmt(elapsed))]
            for topic in sorted(self._in_total):
                values.append((f"in {topic} Hz", _fmt(self._in[topic] / elapsed)))
                values.append((f"in {topic} total", str(self._in_total[topic])))
            for topic in sorted(self._out_total):
                values.append((f"out {topic} Hz", _fmt(self._out[topic] / elapsed)))
                values.append((f"out {topic} total", str(self._out_total[topic])))
            n_drops = sum(self._drops.values())
            values.append(("dropped", str(n_drops)))
            values.append(("dropped total", str(self._drops_total)))
            for reason, n in self._drops.most_common():
                values.append((f"dropped: {reason}", str(n)))
            for reason, n in self._warnings.most_common():
                values.append((f"warning: {reason}", str(n)))
            if self._latencies:
                lat = np.asarray(self._latencies) * 1e3
                values.append(("latency median ms", _fmt(float(np.median(lat)))))
                values.append(("latency max ms", _fmt(float(lat.max()))))
            for key in sorted(self._samples):
                v = np.asarray(self._samples[key])
                if v.size:
                    values.append((f"{key} mean", _fmt(float(v.mean()))))
                    values.append((f"{key} max", _fmt(float(v.max()))))
            for key, n in sorted(self._notes.items()):
                values.append((key, str(n)))
            values.append(("busy %", _fmt(100.0 * self._busy_s / elapsed)))
            values.append(("time jumps", str(self._jumps)))
            silent_s = None if self._last_input is None else now - self._last_input
            if self._errors:
                level, message = DiagnosticStatus.ERROR, f"{self._errors} internal error(s)"
            elif n_drops:
                top, n = self._drops.most_common(1)[0]
                level, message = DiagnosticStatus.WARN, f"dropped {n_drops} input(s), e.g. {n}x {top}"
            elif self._warnings:
                top, n = self._warnings.most_common(1)[0]
                level, message = DiagnosticStatus.WARN, f"{n}x {top}"
            elif silent_s is not None and silent_s > 3 * elapsed and silent_s > 3.0:
                level, message = DiagnosticStatus.WARN, f"no input for {silent_s:.0f} s"
            else:
                rate_in = sum(self._in.values()) / elapsed
                rate_out = sum(self._out.values()) / elapsed
                level, message = DiagnosticStatus.OK, f"{rate_in:.1f} msg/s in, {rate_out:.1f} msg/s out"
            if reset:
                self._window_start = now
                self._in.clear()
                self._out.clear()
                self._drops.clear()
                self._warnings.clear()
                self._latencies.clear()
                self._samples.clear()
                self._notes.clear()
                self._busy_s = 0.0
                self._errors = 0
        return DiagnosticStatus(level=level, name=self.name, message=message, hardware_id=self.hardware_id,
                                values=[KeyValue(key=k, value=v) for k, v in values])

    def publish(self) -> None:
        """Publish the window's status now (the timer calls this every period)."""
        if self.pub is None:
            return
        try:
            msg = DiagnosticArray(status=[self.status()])
            msg.header.stamp = self.node.get_clock().now().to_msg()
            self.pub.publish(msg)
        except Exception:  # noqa: BLE001 - diagnostics never take a node down (e.g. at shutdown)
            pass


def status_values(status: DiagnosticStatus) -> dict:
    """``{key: value}`` of a DiagnosticStatus (values as strings)."""
    return {kv.key: kv.value for kv in status.values}
