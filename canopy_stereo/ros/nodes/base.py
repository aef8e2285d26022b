"""What every canopy_stereo node shares: QoS, drop accounting, guarded callbacks, ``main``.

QoS: inputs use sensor-data QoS, outputs are reliable (``reliability`` parameter);
both can be changed per topic with ROS 2's ``qos_overrides`` parameters, e.g.
``qos_overrides./stereo/left/image_raw.subscription.reliability: reliable`` for
lossless large images between processes.

A bad message (wrong encoding, size mismatch against the rig, an unpaired
frame) is *dropped*: the node logs the reason (the first time, then at most
every few seconds per reason with a count) and keeps running. Unexpected
exceptions in a callback are logged as errors and the message is dropped too;
a node never dies from its input.
"""
from __future__ import annotations

import functools
import sys
import threading
import time
import traceback
from collections import Counter

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.qos import RELIABILITY_CHOICES, publisher_qos, subscription_qos
from canopy_stereo.ros.context import tune_node_process

#: Namespace of the nodes when none is given (``--ros-args -r __ns:=/x`` overrides it).
DEFAULT_NAMESPACE = "/stereo"

#: Seconds between repeated log lines for the same drop reason.
DROP_LOG_PERIOD_S = 5.0

#: Distinct drop reasons counted one by one; later ones count as "other reasons" (a sender
#: varying its image sizes must not grow the counters without bound).
MAX_DROP_REASONS = 64


class CanopyNode(Node):
    """Base node: ``reliability`` parameter, publishers/subscriptions with the
    package's QoS, :meth:`drop` and :meth:`guarded` callbacks.

    Keyword arguments go to :class:`rclpy.node.Node` (``context``, ``namespace``,
    ``parameter_overrides``, ``cli_args``, ...). Counters: ``counts`` (received,
    published, ...) and ``drops`` (reason -> count), both thread-safe to read.
    """

    def __init__(self, node_name: str, **kwargs):
        kwargs.setdefault("namespace", DEFAULT_NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.declare_parameter("reliability", "reliable", ParameterDescriptor(
            description=f"publisher reliability: {' or '.join(RELIABILITY_CHOICES)}", read_only=True))
        self.counts: Counter = Counter()
        self.busy_s = 0.0
        self.drops: Counter = Counter()
        self._drop_logged: dict[str, float] = {}
        self._stats_lock = threading.Lock()
        self._busy = 0
        self.last_active = time.monotonic()  # entry or exit of the latest guarded callback
        self._idle = threading.Condition()
        self._closing = False

    # ------------------------------------------------------------------ pub/sub
    def make_publisher(self, msg_type, topic: str):
        """Publisher with the node's reliability, keep last 1 (overridable per topic with the
        standard ``qos_overrides.<topic>.publisher.<policy>`` parameters)."""
        return self.create_publisher(msg_type, topic,
                                     publisher_qos(self.get_parameter("reliability").value),
                                     qos_overriding_options=QoSOverridingOptions.with_default_policies())

    def make_subscription(self, msg_type, topic: str, callback, depth: int | None = None, **kwargs):
        """Sensor-data QoS subscription whose callback is :meth:`guarded`.

        ``qos_overrides.<topic>.subscription.reliability: reliable`` (a node parameter)
        makes it reliable: large images between processes are then never lost.
        """
        return self.create_subscription(msg_type, topic, self.guarded(callback), subscription_qos(depth),
                                        qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                                        **kwargs)

    # ------------------------------------------------------------------ accounting
    def count(self, what: str, n: int = 1) -> None:
        """Add ``n`` to the counter ``what``."""
        with self._stats_lock:
            self.counts[what] += n

    def drop(self, reason: str, what: str = "message") -> None:
        """Count and log a dropped input (rate-limited per reason)."""
        key = f"{what}: {reason}"
        now = time.monotonic()
        with self._stats_lock:
            if key not in self.drops and len(self.drops) >= MAX_DROP_REASONS:
                key = f"{what}: other reasons"  # hostile input varying its sizes: bounded counters
            self.drops[key] += 1
            n = self.drops[key]
            last = self._drop_logged.get(key)
            if last is not None and now - last < DROP_LOG_PERIOD_S:
                return
            self._drop_logged[key] = now
        suffix = f" ({n} so far)" if n > 1 else ""
        detail = f" (last: {reason})" if key.endswith(": other reasons") else ""
        self.get_logger().warning(f"dropped {key}{detail}{suffix}")

    def guarded(self, fn):
        """Wrap a callback: user-fixable errors drop the message, anything else is
        logged with its traceback; the node keeps running either way."""

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            with self._idle:
                if self._closing:
                    return None
                self._busy += 1
                self.last_active = time.monotonic()
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            except CanopyStereoError as exc:
                self.drop(str(exc))
            except Exception as exc:  # noqa: BLE001 - a node must survive its input
                tb = traceback.format_exc(limit=4)
                self.drop(f"internal error {type(exc).__name__}: {exc}")
                self.get_logger().debug(tb)
            finally:
                with self._stats_lock:
                    self.busy_s += time.perf_counter() - t0
                with self._idle:
                    self._busy -= 1
                    self.last_active = time.monotonic()
                    self._idle.notify_all()
            return None

        return wrapper

    @property
    def busy(self) -> bool:
        """True while one of the node's guarded callbacks runs."""
        with self._idle:
            return self._busy > 0

    def idle_for(self) -> float:
        """Seconds since the node last started or finished a callback (0 while one runs)."""
        with self._idle:
            return 0.0 if self._busy > 0 else time.monotonic() - self.last_active

    def destroy_node(self):
        """Refuse new callbacks, wait (up to 30 s) for running ones, then destroy."""
        with self._idle:
            self._closing = True
            self._idle.wait_for(lambda: self._busy == 0, timeout=30.0)
        return super().destroy_node()

    def stats(self) -> dict:
        """Snapshot ``{"counts": {...}, "drops": {...}, "busy_s": seconds in callbacks}``."""
        with self._stats_lock:
            return {"counts": dict(self.counts), "drops": dict(self.drops), "busy_s": self.busy_s}


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def install_stop_signals() -> None:
    """Make SIGINT and SIGTERM raise :class:`KeyboardInterrupt` in the main thread.

    Executables handle it by stopping their executor, letting running callbacks
    finish, destroying the nodes and only then shutting ROS down (rclpy's own
    handlers would invalidate the context under running callbacks).
    """
    import signal

    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)


def spin_until_interrupted(executor, context=None) -> None:
    """Spin ``executor`` in short slices (so signals are handled) until interrupted or shut down."""
    while context is None or context.ok():
        executor.spin_once(timeout_sec=0.1)


def run_node(factory, args=None) -> int:
    """Entry point body of a node executable: init, build, spin until Ctrl-C/SIGTERM.

    ``factory()`` builds the node after ``rclpy.init`` (so ``--ros-args`` apply).
    A configuration error (:class:`CanopyStereoError`, e.g. no rig) is printed as
    one line and gives exit status 2.
    """
    from rclpy.executors import SingleThreadedExecutor

    args = sys.argv if args is None else args
    tune_node_process()
    rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    install_stop_signals()
    node = executor = None
    try:
        node = factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        spin_until_interrupted(executor, rclpy.get_default_context())
    except CanopyStereoError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
