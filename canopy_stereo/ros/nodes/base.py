"""What every canopy_stereo node shares: QoS, drop accounting, diagnostics, parameters,
guarded callbacks, ``main``.

QoS (:mod:`canopy_stereo.ros.qos`): inputs are reliable, keep last
:data:`~canopy_stereo.ros.qos.INPUT_DEPTH` (the newest frames win when a node falls
behind, so latency stays bounded; Fast DDS loses most ~1 MB best-effort samples
between processes); outputs are reliable (``reliability`` parameter), keep last
:data:`~canopy_stereo.ros.qos.OUTPUT_DEPTH`, and serve reliable and best-effort
(sensor-data) subscribers alike. Every policy can be changed per topic with
rclpy's standard ``qos_overrides`` parameters, e.g.
``qos_overrides./stereo/left/image_raw.subscription.reliability: best_effort``
for a driver that publishes best effort.

Diagnostics (:mod:`canopy_stereo.ros.diagnostics`): every node publishes its input
and output rates, drops with reasons, latency and statistics on ``/diagnostics``
every ``diagnostic_period`` seconds.

Parameters: :meth:`CanopyNode.declare_number` and friends declare parameters with a
description and, for numbers, an integer or floating-point range; an integer given
for a floating-point parameter (``-p fps:=10``, ``ros2 param set ... 1``) is
accepted as that number; a value out of range or of the wrong type stops the
node with one line naming the parameter (exit status 2).

A bad message (wrong encoding, size mismatch against the rig, an unpaired
frame) is *dropped*: the node logs the reason (the first time, then at most
every few seconds per reason with a count) and keeps running. Unexpected
exceptions in a callback are logged as errors and the message is dropped too;
a node never dies from its input.
"""
from __future__ import annotations

import functools
import os
import sys
import threading
import time
import traceback
from collections import Counter, deque

import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException, ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos_overriding_options import QoSOverridingOptions

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.context import init_ros, tune_node_process
from canopy_stereo.ros.diagnostics import DEFAULT_PERIOD_S, NodeDiagnostics
from canopy_stereo.ros.intra_process import IntraProcessBus, LocalSubscription
from canopy_stereo.ros.params import flag_descriptor, number_descriptor, text_descriptor
from canopy_stereo.ros.qos import OUTPUT_DEPTH, RELIABILITY_CHOICES, publisher_qos, sensor_data_qos, subscription_qos
from canopy_stereo.ros.stamps import ZERO_STAMP_CHOICES, StampCheck

#: Namespace of the nodes when none is given (``--ros-args -r __ns:=/x`` overrides it).
DEFAULT_NAMESPACE = "/stereo"

#: Seconds between repeated log lines for the same drop reason.
DROP_LOG_PERIOD_S = 5.0

#: Frame size (width, height) nodes warm up on when the rig's image size is not given.
WARM_UP_SIZE = (640, 480)

#: Distinct drop reasons counted one by one; later ones count as "other reasons" (a sender
#: varying its image sizes must not grow the counters without bound).
MAX_DROP_REASONS = 64


class CanopyNode(Node):
    """Base node: ``reliability`` parameter, publishers/subscriptions with the
    package's QoS, :meth:`drop` and :meth:`guarded` callbacks.

    Keyword arguments go to :class:`rclpy.node.Node` (``context``, ``namespace``,
    ``parameter_overrides``, ``cli_args``, ...), except ``intra_process``: an
    :class:`~canopy_stereo.ros.intra_process.IntraProcessBus` shared with the other nodes of
    the process (:class:`~canopy_stereo.ros.graph.CanopyGraph` passes one), over which
    messages between them travel without DDS. Counters: ``counts`` (received,
    published, ...) and ``drops`` (reason -> count), both thread-safe to read.
    """

    def __init__(self, node_name: str, *, intra_process: IntraProcessBus | None = None, **kwargs):
        kwargs.setdefault("namespace", DEFAULT_NAMESPACE)
        super().__init__(node_name, **kwargs)
        self.intra_process = intra_process
        self.local_subscriptions: list[LocalSubscription] = []
        self._local_topics: list[str] = []
        self.add_pre_set_parameters_callback(self._integers_for_doubles)
        self.declare_text("reliability", "reliable", "reliability of the node's publishers",
                          choices=RELIABILITY_CHOICES, read_only=True)
        self.declare_number("diagnostic_period", DEFAULT_PERIOD_S,
                            "seconds between two reports on /diagnostics (0 = none)",
                            minimum=0.0, maximum=3600.0, read_only=True)
        self.diagnostics = NodeDiagnostics(self, float(self.get_parameter("diagnostic_period").value),
                                           self._hardware_id())
        self.counts: Counter = Counter()
        self.busy_s = 0.0
        self.drops: Counter = Counter()
        self.warnings: Counter = Counter()  # reason -> inputs kept with a warning (see warn)
        self.warm_up_s = 0.0  # seconds the warm-up before subscribing took (see warm_up)
        self._drop_logged: dict[str, float] = {}
        self._jump_logged = float("-inf")
        self._jumps_unlogged = 0
        self._stats_lock = threading.Lock()
        self._busy = 0
        self.last_active = time.monotonic()  # entry or exit of the latest guarded callback
        self._idle = threading.Condition()
        self._closing = False
        self._workers: list[LatestOnly] = []

    def _hardware_id(self) -> str:
        """``hardware_id`` of the node's diagnostics (subclasses: the device they drive)."""
        return self.get_fully_qualified_name()

    # ------------------------------------------------------------------ parameters
    def declare_parameters(self, namespace, parameters, ignore_override: bool = False):
        """rclpy's ``declare_parameters``, with an integer override of a floating-point
        parameter taken as that number and bad values raised as :class:`CanopyStereoError`."""
        for entry in parameters:
            name = f"{namespace}.{entry[0]}" if namespace else entry[0]
            value = entry[1] if len(entry) > 1 else None
            descriptor = entry[2] if len(entry) > 2 else None
            is_double = (isinstance(value, float)
                         or (isinstance(value, Parameter.Type) and value == Parameter.Type.DOUBLE)
                         or (descriptor is not None and descriptor.type == ParameterType.PARAMETER_DOUBLE))
            override = self._parameter_overrides.get(name)
            if is_double and override is not None and override.type_ == Parameter.Type.INTEGER:
                self._parameter_overrides[name] = Parameter(name, Parameter.Type.DOUBLE, float(override.value))
        try:
            return super().declare_parameters(namespace, parameters, ignore_override)
        except InvalidParameterValueException as exc:
            text = str(exc)
            reason = text.split("Reason: ", 1)[-1].rsplit(": ", 1)[0]
            raise CanopyStereoError(f"node {self.get_name()}: {reason}") from None
        except InvalidParameterTypeException as exc:
            raise CanopyStereoError(f"node {self.get_name()}: {str(exc).rsplit(': ', 1)[0]}") from None

    def _integers_for_doubles(self, parameters: list) -> list:
        """Pre-set callback: ``ros2 param set NODE scale 1`` sets a double parameter to 1.0."""
        out = []
        for p in parameters:
            if p.type_ == Parameter.Type.INTEGER and self.has_parameter(p.name):
                try:
                    if self.describe_parameter(p.name).type == ParameterType.PARAMETER_DOUBLE:
                        p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
                except ParameterException:
                    pass
            out.append(p)
        return out

    def declare_number(self, name: str, default, description: str, *, minimum, maximum, step=0,
                       read_only: bool = False):
        """Declare an integer (``default`` an int) or floating-point parameter with its range."""
        return self.declare_parameter(name, default, number_descriptor(
            description, minimum=minimum, maximum=maximum, step=step, read_only=read_only,
            integer=isinstance(default, int) and not isinstance(default, bool)))

    def declare_text(self, name: str, default: str, description: str, *, choices=None,
                     read_only: bool = False):
        """Declare a string parameter (``choices`` are listed in the description)."""
        return self.declare_parameter(name, default, text_descriptor(description, choices=choices,
                                                                     read_only=read_only))

    def declare_flag(self, name: str, default: bool, description: str, *, read_only: bool = False):
        """Declare a boolean parameter."""
        return self.declare_parameter(name, bool(default), flag_descriptor(description, read_only=read_only))

    # ------------------------------------------------------------------ pub/sub
    def make_publisher(self, msg_type, topic: str):
        """Publisher with the node's reliability, keep last :data:`OUTPUT_DEPTH` (overridable
        per topic with the standard ``qos_overrides.<topic>.publisher.<policy>`` parameters);
        its messages are counted in the node's diagnostics."""
        pub = self.create_publisher(msg_type, topic,
                                    publisher_qos(self.get_parameter("reliability").value, OUTPUT_DEPTH),
                                    qos_overriding_options=QoSOverridingOptions.with_default_policies())
        if self.intra_process is not None:
            self.intra_process.register_publisher(pub.topic_name)
            self._local_topics.append(pub.topic_name)
        return _CountedPublisher(pub, self.diagnostics, self.intra_process)

    def make_subscription(self, msg_type, topic: str, callback, *, depth: int | None = None,
                          sensor_data: bool = False, with_info: bool = False, parse=None, **kwargs):
        """Reliable keep-last subscription (:func:`~canopy_stereo.ros.qos.subscription_qos`)
        whose callback is :meth:`guarded` and counted in the node's diagnostics.
        ``sensor_data``: REP 2003's sensor-data QoS instead (best effort, keep last), for
        inputs small enough to cross processes best effort (compressed images).

        ``qos_overrides.<topic>.subscription.reliability: best_effort`` (a node parameter)
        accepts a best-effort publisher (large messages between processes may then be lost).

        ``with_info``: ``callback(msg, info)`` with rclpy's message info (a dict with
        ``received_timestamp`` and ``source_timestamp``, ns; None from an intra-process bus and in a
        node process spinning rclpy's events executor, :func:`node_executor_kind`).

        With an intra-process bus, a topic that another node of the bus publishes is
        received from the bus instead (a :class:`~canopy_stereo.ros.intra_process.LocalSubscription`
        with the same keep-last depth; its QoS overrides do not apply).

        ``parse``: over DDS, take the serialized message (rclpy's ``raw``) and give the callback
        ``parse(data)``, a read-only view with the message's fields (:mod:`canopy_stereo.ros.cdr_views`:
        large arrays are read in place instead of being deserialised and copied); messages of an
        intra-process bus are given as they are.
        """
        diagnostics = self.diagnostics
        name = topic

        def counted(msg, info=None):
            stamp = _header_stamp_ns(msg)
            diagnostics.received(name, stamp)
            return callback(msg, info) if with_info else callback(msg)

        if self.intra_process is not None and not kwargs:
            resolved = self.resolve_topic_name(topic)
            if self.intra_process.publisher_count(resolved) > 0:
                name = resolved
                sub = self.intra_process.subscribe(self, resolved, self.guarded(counted),
                                                   int(subscription_qos(depth).depth))
                self.local_subscriptions.append(sub)
                return sub
        qos = sensor_data_qos(depth) if sensor_data else subscription_qos(depth)
        if parse is not None:
            kwargs["raw"] = True

            def parsed(data, info=None):
                return counted(parse(data), info)

            guarded = self.guarded(parsed)
        else:
            guarded = self.guarded(counted)
        subscribed = guarded
        # rclpy passes the message info to callbacks of exactly two arguments; its events executor
        # has none to pass (the callback gets None: the time of the call is the receive time)
        if with_info and _process_executor != "events":
            def with_message_info(msg, info):
                return guarded(msg, info)

            subscribed = with_message_info
        kwargs.setdefault("event_callbacks", SubscriptionEventCallbacks(
            message_lost=lambda info: self._samples_lost(topic, info)))
        sub = self.create_subscription(msg_type, topic, subscribed, qos,
                                       qos_overriding_options=QoSOverridingOptions.with_default_policies(),
                                       **kwargs)
        name = sub.topic_name
        return sub

    def _samples_lost(self, topic: str, info) -> None:
        """Fast DDS reports samples a publisher sent that will never arrive (its history dropped
        them before this reader had them all): drops on /diagnostics, naming the topic."""
        for _ in range(max(0, int(getattr(info, "total_count_change", 0)))):
            self.drop("lost in transport: the publisher's sample never arrived whole (DDS sample lost; "
                      "README: camera drivers that are not ours)", self.resolve_topic_name(topic))

    # ------------------------------------------------------------------ accounting
    def count(self, what: str, n: int = 1) -> None:
        """Add ``n`` to the counter ``what``."""
        with self._stats_lock:
            self.counts[what] += n

    def time_jump_handler(self, stream_names):
        """An ``on_jump`` callback for the synchronizers of :mod:`canopy_stereo.bag.pairing`:
        one log line per backwards time jump, counted in the diagnostics."""
        def on_jump(jump) -> None:
            self.count("time_jumps")
            self.diagnostics.time_jump()
            now = time.monotonic()
            with self._stats_lock:  # a short looping bag jumps every pass: at most a line per period
                self._jumps_unlogged += 1
                if now - self._jump_logged < DROP_LOG_PERIOD_S:
                    return
                self._jump_logged, n, self._jumps_unlogged = now, self._jumps_unlogged, 0
            more = f" ({n} jumps since the last report)" if n > 1 else ""
            self.get_logger().warning(
                f"time jumped back {jump.back_s:.3f} s ({stream_names[jump.stream]} stamps): pairing "
                f"reset, {jump.dropped} queued message(s) from before the jump dropped{more}")
        return on_jump

    def drop(self, reason: str, what: str = "message", *, log: bool = True) -> None:
        """Count and log a dropped input (rate-limited per reason; ``log=False``: count only)."""
        key = f"{what}: {reason}"
        now = time.monotonic()
        self.diagnostics.dropped(key, internal=reason.startswith("internal error"))
        with self._stats_lock:
            if key not in self.drops and len(self.drops) >= MAX_DROP_REASONS:
                key = f"{what}: other reasons"  # hostile input varying its sizes: bounded counters
            self.drops[key] += 1
            n = self.drops[key]
            if not log:
                return
            last = self._drop_logged.get(key)
            if last is not None and now - last < DROP_LOG_PERIOD_S:
                return
            self._drop_logged[key] = now
        suffix = f" ({n} so far)" if n > 1 else ""
        detail = f" (last: {reason})" if key.endswith(": other reasons") else ""
        self.get_logger().warning(f"dropped {key}{detail}{suffix}")

    def declare_frame_size(self) -> None:
        """Declare ``image_width`` and ``image_height`` (the rig file sets them): the size of the
        frames the node prepares for before subscribing (see :meth:`warm_up_size`)."""
        for name in ("image_width", "image_height"):
            self.declare_number(name, 0, f"{name.split('_')[1]} of the rig's images in pixels (the rig file "
                                "sets it): kernels and buffers are prepared on frames of this size before "
                                f"the node subscribes; 0 = {WARM_UP_SIZE[0]}x{WARM_UP_SIZE[1]}",
                                minimum=0, maximum=16384, read_only=True)

    def warm_up_size(self) -> tuple[int, int]:
        """``(width, height)`` of the frame to warm up on: ``image_width``/``image_height`` when
        declared and set, else :data:`WARM_UP_SIZE`."""
        if self.has_parameter("image_width") and self.has_parameter("image_height"):
            w, h = (int(self.get_parameter(n).value or 0) for n in ("image_width", "image_height"))
            if w > 0 and h > 0:
                return w, h
        return WARM_UP_SIZE

    def warm_up(self, what: str, fn) -> float:
        """Run ``fn()`` once before the node subscribes: its numba kernels are loaded (or, with
        an empty cache, compiled) and its buffers allocated on a frame of the rig's size, so
        that the first frame of a stream is processed as fast as the others. Logs how long it
        took; a failure is logged and the node goes on (the first frame then pays). Returns the
        seconds spent."""
        t0 = time.perf_counter()
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - a warm-up never stops a node
            self.get_logger().warning(f"warm-up failed ({type(exc).__name__}: {exc}); the first "
                                      "frame will load the kernels")
        self.warm_up_s = time.perf_counter() - t0
        self.diagnostics.restart()  # the first report covers the node's time ready, not its warm-up
        self.get_logger().info(f"ready in {self.warm_up_s:.2f} s ({what}) before subscribing")
        return self.warm_up_s

    def warn(self, reason: str, what: str = "message") -> None:
        """Report an input that is kept but suspicious (WARN on /diagnostics; logged at most
        every :data:`DROP_LOG_PERIOD_S` per reason)."""
        key = f"{what}: {reason}"
        self.diagnostics.warned(key)
        now = time.monotonic()
        with self._stats_lock:
            self.warnings[key] += 1
            n = self.warnings[key]
            last = self._drop_logged.get(key)
            if last is not None and now - last < DROP_LOG_PERIOD_S:
                return
            self._drop_logged[key] = now
        self.get_logger().warning(f"{key}" + (f" ({n} so far)" if n > 1 else ""))

    def declare_stamp_checks(self, n_streams: int) -> StampCheck:
        """Declare ``zero_stamps`` and ``max_stamp_gap`` and return the :class:`StampCheck` of
        ``n_streams`` input streams they configure (:mod:`canopy_stereo.ros.stamps`)."""
        self.declare_text("zero_stamps", "restamp", "frames stamped 0 (a driver that does not stamp): "
                          "restamp = use the receive time, drop = drop them; a warning either way",
                          choices=ZERO_STAMP_CHOICES, read_only=True)
        self.declare_number("max_stamp_gap", 0.0, "seconds a frame's stamp may differ from its receive "
                            "time before a warning naming the gap (0 = never; a bag played with its "
                            "recorded stamps is far from now)", minimum=0.0, maximum=1e9, read_only=True)
        zero = self.get_parameter("zero_stamps").value
        if zero not in ZERO_STAMP_CHOICES:
            raise CanopyStereoError(f"zero_stamps must be one of {', '.join(ZERO_STAMP_CHOICES)}, got {zero!r}")
        return StampCheck(n_streams, zero_stamps=zero, max_gap_s=float(self.get_parameter("max_stamp_gap").value))

    def checked_stamp(self, check: StampCheck, stream: int, stamp_ns: int, what: str, *,
                      info: dict | None = None) -> int | None:
        """The stamp to use for an input of ``stream`` stamped ``stamp_ns`` (None: dropped as a
        duplicate or a zero stamp), warnings and drops reported as ``what``. The receive time is
        the middleware's (``info['received_timestamp']``, see :meth:`make_subscription`), else now."""
        received = (info or {}).get("received_timestamp") or self.get_clock().now().nanoseconds
        verdict = check.check(stream, stamp_ns, int(received))
        for reason in verdict.warnings:
            self.warn(reason, what)
        if verdict.stamp_ns is None:
            self.drop(verdict.drop_reason, what)
        return verdict.stamp_ns

    def drop_unpaired(self, dropped, streams) -> None:
        """Count and log what a synchronizer of :mod:`canopy_stereo.bag.pairing` dropped
        (``streams[d.stream]`` names each input); drops of a time jump are counted only
        (the jump itself is logged once, by :meth:`time_jump_handler`'s callback)."""
        for d in dropped:
            self.drop(d.reason, streams[d.stream], log=not d.after_jump)

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
                dt = time.perf_counter() - t0
                self.diagnostics.busy(dt)
                with self._stats_lock:
                    self.busy_s += dt
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

    def latest_only(self, fn, what: str, *, depth: int = 1, workers: int = 1) -> LatestOnly:
        """``workers`` threads that run ``fn`` on the newest submitted jobs (see :class:`LatestOnly`)."""
        worker = LatestOnly(self, fn, what, depth, workers=workers)
        self._workers.append(worker)
        return worker

    def destroy_node(self):
        """Refuse new callbacks, wait (up to 30 s) for running ones, then destroy."""
        with self._idle:
            self._closing = True
        for sub in self.local_subscriptions:
            sub.close()
        if self.intra_process is not None:
            for topic in self._local_topics:
                self.intra_process.unregister_publisher(topic)
            self._local_topics = []
        for worker in self._workers:
            worker.close()
        with self._idle:
            self._idle.wait_for(lambda: self._busy == 0, timeout=30.0)
        return super().destroy_node()

    def stats(self) -> dict:
        """Snapshot ``{"counts": {...}, "drops": {...}, "busy_s": seconds in callbacks}``."""
        with self._stats_lock:
            return {"counts": dict(self.counts), "drops": dict(self.drops), "busy_s": self.busy_s}


class LatestOnly:
    """Newest-frames-win processing for a node's slow stage.

    The node's callbacks only pair inputs and :meth:`submit` complete jobs; ``workers``
    threads run ``fn(*job)`` (as a :meth:`CanopyNode.guarded` callback: errors are drops,
    the node counts as busy) on the waiting jobs in order. At most ``depth`` jobs wait:
    when another arrives the oldest waiting one is dropped as superseded. So a short stall
    is absorbed, a camera faster than the stage gets its newest pairs processed, latency
    stays bounded (``depth`` jobs at most wait), and the node's inputs are always drained
    (no pair loses one of its images in a full queue).

    With several workers, consecutive jobs run at once (frame-level parallelism: no job is
    split, so each gives the same result as on one worker). A job publishes its results
    inside :meth:`in_turn`, which waits until every job taken before it has finished: the
    outputs leave in the order the jobs came, whichever finishes first.
    """

    def __init__(self, node: CanopyNode, fn, what: str, depth: int = 1, *, workers: int = 1):
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.node, self.what, self.depth, self.workers = node, what, int(depth), int(workers)
        self._fn = node.guarded(fn)
        self._cond = threading.Condition()
        self._jobs: deque = deque()
        self._calls: deque = deque()  # functions to run on a worker thread first (see call)
        self._stop = False
        self._taken = 0  # jobs taken by the workers so far (the next job's turn number)
        self._turn = 0  # the oldest taken job not finished yet
        self._finished: set[int] = set()  # finished jobs after self._turn
        self._local = threading.local()
        self._threads = [threading.Thread(target=self._run, name=f"{node.get_name()}:latest{k or ''}", daemon=True)
                         for k in range(self.workers)]
        for thread in self._threads:
            thread.start()

    def submit(self, *job) -> None:
        """Queue ``job`` for ``fn``; drops the oldest waiting job when ``depth`` already wait."""
        with self._cond:
            self._jobs.append(job)
            superseded = 0
            while len(self._jobs) > self.depth:
                self._jobs.popleft()
                superseded += 1
            self._cond.notify()
        for _ in range(superseded):
            self.node.drop("superseded by newer ones while the node was busy", self.what)

    def waiting(self) -> int:
        """Jobs submitted and not taken by a worker yet."""
        with self._cond:
            return len(self._jobs)

    def call(self, fn) -> None:
        """Run ``fn()`` on a worker thread, before any waiting job, and return when it is done
        (re-raising what it raised): a warm-up whose per-thread state (numba's thread pool of
        the calling thread) the jobs then find ready."""
        done, raised = threading.Event(), []

        def run() -> None:
            try:
                fn()
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller
                raised.append(exc)
            finally:
                done.set()

        with self._cond:
            self._calls.append(run)
            self._cond.notify()
        done.wait()
        if raised:
            raise raised[0]

    def in_turn(self):
        """Context for a job's publishing: entered once every job taken before the calling
        one has finished (at once with one worker, or outside a job)."""
        return _Turn(self, getattr(self._local, "turn", None))

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._jobs or self._calls or self._stop)
                if self._stop:
                    return
                if self._calls:
                    call = self._calls.popleft()
                    self._cond.release()
                    try:
                        call()
                    finally:
                        self._cond.acquire()
                    continue
                job = self._jobs.popleft()
                turn, self._taken = self._taken, self._taken + 1
                # busy from here on, so that the node never looks idle with a job taken
                with self.node._idle:
                    self.node._busy += 1
            self._local.turn = turn
            try:
                self._fn(*job)
            finally:
                self._local.turn = None
                with self._cond:
                    self._finished.add(turn)
                    while self._turn in self._finished:
                        self._finished.discard(self._turn)
                        self._turn += 1
                    self._cond.notify_all()
                with self.node._idle:
                    self.node._busy -= 1
                    self.node._idle.notify_all()

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop after the running jobs (waiting ones are discarded)."""
        with self._cond:
            self._stop = True
            self._cond.notify_all()
        for thread in self._threads:
            if threading.current_thread() is not thread:
                thread.join(timeout_s)


class _Turn:
    """:meth:`LatestOnly.in_turn`'s context: waits for the jobs taken before ``turn``."""

    def __init__(self, owner: LatestOnly, turn: int | None):
        self._owner, self._turn = owner, turn

    def __enter__(self) -> None:
        if self._turn is None:
            return
        owner = self._owner
        with owner._cond:
            owner._cond.wait_for(lambda: owner._turn >= self._turn or owner._stop)

    def __exit__(self, *exc) -> None:
        return None


def _header_stamp_ns(msg) -> int | None:
    header = getattr(msg, "header", None)
    if header is None:
        return None
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


class _CountedPublisher:
    """An rclpy publisher whose ``publish`` also reports to the node's diagnostics and hands
    the message to the local subscriptions of an intra-process bus (every other attribute
    is the publisher's own)."""

    def __init__(self, publisher, diagnostics: NodeDiagnostics, bus: IntraProcessBus | None = None):
        self._publisher = publisher
        self._diagnostics = diagnostics
        self._bus = bus
        self._topic = publisher.topic_name

    def publish(self, msg) -> None:
        self._publisher.publish(msg)
        if self._bus is not None:
            self._bus.deliver(self._topic, msg)
        self._diagnostics.published(self._topic, _header_stamp_ns(msg))

    @property
    def publisher(self):
        """The rclpy publisher."""
        return self._publisher

    def __getattr__(self, name):
        return getattr(self._publisher, name)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def install_stop_signals() -> None:
    """Make SIGINT, SIGTERM and SIGHUP raise :class:`KeyboardInterrupt` in the main thread.

    Executables handle it by stopping their executor, letting running callbacks
    finish, destroying the nodes and only then shutting ROS down (rclpy's own
    handlers would invalidate the context under running callbacks).
    """
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _interrupt)


def spin_until_interrupted(executor, context=None) -> None:
    """Spin ``executor`` in short slices (so signals are handled) until interrupted or shut down."""
    while context is None or context.ok():
        executor.spin_once(timeout_sec=0.1)


#: Executor of a node process (:func:`node_executor`), set by :func:`run_node` before the node is
#: built: ``events`` or ``single`` (None outside a node executable: tests, ``canopy_graph``).
_process_executor: str | None = None


def events_executor_available() -> bool:
    """Whether this rclpy has the events executor (``rclpy.experimental.EventsExecutor``)."""
    try:
        from rclpy.experimental import EventsExecutor  # noqa: F401
    except ImportError:
        return False
    return True


def node_executor_kind() -> str:
    """``events`` or ``single``: the executor a node process spins with. ``CANOPY_STEREO_EXECUTOR``
    ``events`` (default; ``single`` where this rclpy has no events executor) or ``single``.

    rclpy's events executor (C++, event queue) takes 0.5 ms of CPU per received 640x480 mono
    image where ``SingleThreadedExecutor``, which rebuilds its wait set in Python for every wait,
    takes 0.85-1.2 ms (more with more subscriptions, publishers and their event handlers): with a
    dozen messages per pair across the graph, several ms per pair. It does not hand callbacks
    rclpy's message info: such nodes take the receive time when the callback runs."""
    choice = os.environ.get("CANOPY_STEREO_EXECUTOR", "events").strip().lower()
    if choice not in ("events", "single"):
        raise CanopyStereoError(f"CANOPY_STEREO_EXECUTOR must be 'events' or 'single', got {choice!r}")
    return "events" if choice == "events" and events_executor_available() else "single"


def node_executor(kind: str):
    """A new executor of ``kind`` (:func:`node_executor_kind`)."""
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def run_node(factory, args=None) -> int:
    """Entry point body of a node executable: init, build, spin until Ctrl-C/SIGTERM.

    ``factory()`` builds the node after ``rclpy.init`` (so ``--ros-args`` apply).
    A configuration error (:class:`CanopyStereoError`: no rig, a broken rig file, a bad
    ``--params-file`` or ``--ros-args``, see :func:`~canopy_stereo.ros.context.init_ros`)
    is printed as one line and gives exit status 2.
    """
    args = sys.argv if args is None else args
    tune_node_process(args)  # before rclpy.init: the DDS profile for this node's topics
    try:
        init_ros(args)  # a bad --params-file or --ros-args: one line, exit 2
    except CanopyStereoError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    install_stop_signals()
    node = executor = None
    global _process_executor
    try:
        kind = _process_executor = node_executor_kind()
        node = factory()
        executor = node_executor(kind)
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
