"""Replay a bag through the real node graph and record its outputs.

This is ``canopy-stereo run`` (and the engine of ``canopy-stereo demo`` and
``benchmarks/bench_graph.py``): the bag's ``left/image_raw`` and
``right/image_raw`` messages are published into a :class:`~canopy_stereo.ros.graph.CanopyGraph`
built in-process on a private DDS domain; the outputs (``disparity``,
``points2``, ``left/mask``, camera infos) are received by a recorder node and
written to a bag.

Frames and timing: a *frame* is one left image. It is complete when a
``points2`` with its stamp arrives (``rectify_node`` stamps pairs with the left
stamp); frames overtaken by the cloud of a frame published after them, or still
missing when the graph has been idle for ``idle_s``, count as dropped. With
``loop`` the bag plays again and again (its stamps jump back at every pass, which
the nodes handle) until ``stop`` is set; the graph is built once. With ``rate = 0`` the player keeps
at most ``max_in_flight`` frames in the graph (as fast as the graph goes,
without overrunning its queues). Latency is measured from the publication of a
frame's second image to the reception of its cloud.
"""
from __future__ import annotations

import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from canopy_stereo.bag import BagError, BagReader, BagWriter
from canopy_stereo.bag.messages import qos_profiles_yaml
from canopy_stereo.bag.metadata import recording_metadata
from canopy_stereo.bag.msgdefs import type_name
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.compressed_image import COMPRESSED_SUFFIX, IMAGE_TYPE, compressed_topic
from canopy_stereo.io.rig import Rig
from canopy_stereo.ros.context import ros_context, wait_for, wait_for_subscribers
from canopy_stereo.ros.graph import CanopyGraph, GraphOptions
from canopy_stereo.ros.nodes.base import CanopyNode
from canopy_stereo.ros.player import BagPlayer
from canopy_stereo.ros.qos import recording_qos
from canopy_stereo.ros.recorder import has_header, header_stamp_from_cdr


@dataclass
class RunResult:
    """Outcome of :func:`run_bag`.

    Attributes:
        frames_in: left frames published.
        frames_out: clouds received for them.
        frames_dropped: frames that produced no cloud.
        wall_s: seconds from the first published frame to the last cloud.
        latencies_s: per completed frame, second raw image published -> cloud received.
        recorded: the output bag (the last file of a split recording), or None.
        recorded_files: every file of the recording.
        outputs: topic -> list of ``(stamp_ns, CDR bytes)`` for the topics asked to keep.
        graph_stats: node -> counters and drop reasons.
        truncated, problem: the input bag was cut short (and why).
        damage: damaged places of the input bag (one line each: offset, problem, messages lost).
        invalid_messages: input messages skipped because they are not valid CDR (one line each).
        completed_at_s: per completed frame, when its cloud arrived (monotonic seconds).
    """

    frames_in: int = 0
    frames_out: int = 0
    frames_dropped: int = 0
    wall_s: float = 0.0
    latencies_s: list = field(default_factory=list)
    recorded: Path | None = None
    recorded_files: list = field(default_factory=list)
    outputs: dict = field(default_factory=dict)
    graph_stats: dict = field(default_factory=dict)
    truncated: bool = False
    problem: str = ""
    damage: list = field(default_factory=list)
    invalid_messages: list = field(default_factory=list)
    completed_at_s: list = field(default_factory=list)

    @property
    def fps(self) -> float:
        """Clouds per second over :attr:`wall_s`."""
        return self.frames_out / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def latency_median_s(self) -> float:
        return float(np.median(self.latencies_s)) if self.latencies_s else float("nan")

    def summary_lines(self) -> list[str]:
        """Human-readable figures (frames in/out, fps, latency, drops)."""
        lines = [f"frames in: {self.frames_in}, frames out: {self.frames_out}, "
                 f"dropped: {self.frames_dropped}",
                 f"throughput: {self.fps:.2f} frames/s over {self.wall_s:.2f} s"]
        if self.latencies_s:
            lat = np.asarray(self.latencies_s) * 1e3
            lines.append(f"latency raw pair -> points2: median {np.median(lat):.0f} ms, "
                         f"max {lat.max():.0f} ms")
        if self.truncated:
            lines.append(f"input bag truncated: {self.problem}")
        for line in self.damage:
            lines.append(f"input bag damaged: {line}")
        if self.invalid_messages:
            lines.append(f"input messages skipped (not valid CDR): {len(self.invalid_messages)}; "
                         f"first: {self.invalid_messages[0]}")
        for node, st in sorted(self.graph_stats.items()):
            for reason, n in sorted(st.get("drops", {}).items()):
                lines.append(f"{node} dropped {n}x {reason}")
        if self.recorded is not None:
            files = self.recorded_files or [self.recorded]
            lines.append(f"recorded: {', '.join(str(f) for f in files)}")
        return lines


#: Frames tracked at most while waiting for their clouds (older ones count as dropped).
_MAX_TRACKED = 256


class _FrameBook:
    """Frames in flight, completion and latency (thread-safe). Frames are ordered by
    publication, not by stamp, so that stamps may jump back (a looping bag)."""

    def __init__(self):
        self.cond = threading.Condition()
        self.in_flight: dict[int, float] = {}  # left stamp -> publish time, in publication order
        self.right_times: dict[int, float] = {}
        self.frames_in = self.frames_out = self.dropped = 0
        self.first_pub = None
        self.last_out = None
        self.last_activity = time.monotonic()
        self.latencies: list[float] = []
        self.out_times: list[float] = []

    def published(self, is_left: bool, stamp: int, t: float) -> None:
        with self.cond:
            self.last_activity = t
            if self.first_pub is None:
                self.first_pub = t
            if is_left:
                if self.in_flight.pop(stamp, None) is not None:
                    self.dropped += 1  # the same stamp again (a looping bag) before its cloud came
                self.in_flight[stamp] = t
                self.frames_in += 1
                while len(self.in_flight) > _MAX_TRACKED:  # a graph that stopped producing, looped
                    del self.in_flight[next(iter(self.in_flight))]
                    self.dropped += 1
            else:
                self.right_times[stamp] = t
                if len(self.right_times) > 64:
                    self.right_times.pop(min(self.right_times))
            self.cond.notify_all()

    def _pair_time(self, stamp: int) -> float:
        t = self.in_flight[stamp]
        if self.right_times:
            nearest = min(self.right_times, key=lambda s: abs(s - stamp))
            t = max(t, self.right_times[nearest])
        return t

    def completed(self, stamp: int, t: float) -> None:
        with self.cond:
            self.last_activity = t
            if stamp in self.in_flight:
                for s in list(self.in_flight):  # publication order: earlier frames were overtaken
                    if s == stamp:
                        self.latencies.append(t - self._pair_time(s))
                        self.out_times.append(t)
                        self.frames_out += 1
                        self.last_out = t
                    else:
                        self.dropped += 1
                    del self.in_flight[s]
                    if s == stamp:
                        break
            self.cond.notify_all()

    def drop_oldest(self) -> None:
        with self.cond:
            if self.in_flight:
                del self.in_flight[next(iter(self.in_flight))]
                self.dropped += 1
            self.cond.notify_all()


def stereo_input_remap(topics, *, namespace: str, remap: dict[str, str] | None = None) -> dict[str, str]:
    """``remap`` plus, when the bag has no ``<namespace>/left|right/image_raw`` (nor their
    ``/compressed`` topics) after it, the remapping of the bag's one stereo pair recorded under
    another namespace (the bundled ``/stereo/...`` bags played into ``/rig_a``):
    ``/stereo/left/image_raw -> /rig_a/left/image_raw``, the same for the right camera (and for
    ``.../image_raw/compressed``). A bag with several such pairs is left alone (the caller then
    names the topics it has)."""
    remap = dict(remap or {})
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    suffixes = ("image_raw", "image_raw/compressed")
    mapped = {remap.get(t, t) for t in topics}
    if any({f"{ns}/left/{s}", f"{ns}/right/{s}"} <= mapped for s in suffixes):
        return remap
    for suffix in suffixes:
        left = f"/left/{suffix}"
        prefixes = [t[: -len(left)] for t in topics if t.endswith(left) and t not in remap
                    and f"{t[: -len(left)]}/right/{suffix}" in topics]
        if len(prefixes) == 1:
            for side in ("left", "right"):
                remap[f"{prefixes[0]}/{side}/{suffix}"] = f"{ns}/{side}/{suffix}"
            return remap
    return remap


def open_input_bag(bag_path, *, namespace: str = "stereo", remap: dict[str, str] | None = None):
    """Open a bag for the graph and check it has both image topics (after ``remap``).

    The graph reads ``<namespace>/left|right/image_raw`` (``sensor_msgs/Image``); a bag holding
    only compressed images (``sensor_msgs/CompressedImage``, JPEG or PNG) is read from
    image_transport's ``<namespace>/left|right/image_raw/compressed`` (found there when the
    raw topics are absent, or remapped onto them), and rectify_node then takes compressed
    input (:func:`input_transport`).

    Returns ``(reader, topics to play, the left input topic)``. Raises :class:`BagError` when
    the bag is truncated or damaged before any intact pair of input topics, and
    :class:`CanopyStereoError` when it has neither pair of topics (naming the topics it has).
    Cheap (reads the summary), so a CLI checks its input with it before preparing the kernels.
    """
    bag = BagReader(bag_path)
    remap = stereo_input_remap(bag.topics, namespace=namespace, remap=remap)
    damaged = bag.truncated or bool(bag.damage)
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""
    in_left, in_right = f"{ns}/left/image_raw", f"{ns}/right/image_raw"
    play_topics = [t for t in bag.topics if remap.get(t, t) in (in_left, in_right)]
    sides = {remap.get(t, t) for t in play_topics}
    if sides != {in_left, in_right}:  # no raw pair: image_transport's compressed topics
        c_left, c_right = compressed_topic(in_left), compressed_topic(in_right)
        compressed = [t for t in bag.topics if remap.get(t, t) in (c_left, c_right)]
        if {remap.get(t, t) for t in compressed} == {c_left, c_right}:
            return bag, compressed, c_left
    if sides != {in_left, in_right} and damaged:
        raise BagError(f"{bag.path} is {'truncated' if bag.truncated else 'damaged'} ({bag.problem}): "
                       f"no intact {in_left} and {in_right} messages before the damage (topics "
                       f"read: {', '.join(sorted(bag.topics)) or 'none'})")
    if sides != {in_left, in_right}:
        raise CanopyStereoError(
            f"{bag.path} has no {in_left} and {in_right} (nor their /compressed topics) to play (topics: "
            f"{', '.join(sorted(bag.topics)) or 'none'}); use remapping")
    return bag, play_topics, in_left


def input_transport(left_topic: str) -> str:
    """rectify_node's ``image_transport`` for the graph's left input topic (``raw`` or ``compressed``)."""
    return "compressed" if left_topic.endswith(COMPRESSED_SUFFIX) else "raw"


def _with_transport(options: GraphOptions, transport: str) -> GraphOptions:
    """``options`` with rectify_node reading ``transport`` (unless set explicitly)."""
    rectify = options.node_parameters.get("rectify_node", {})
    if transport == "raw" or "image_transport" in rectify:
        return options
    params = {**options.node_parameters, "rectify_node": {**rectify, "image_transport": transport}}
    return replace(options, node_parameters=params)


def run_bag(bag_path, rig: Rig, *, rate: float = 1.0, record=None, options: GraphOptions | None = None,
            domain_id: int | None = None, max_in_flight: int = 2, idle_s: float = 2.0,
            timeout_s: float = 120.0, keep=(), remap: dict | None = None,
            startup_timeout_s: float = 30.0, progress=None, compression: str = "lz4",
            context=None, loop: bool = False, stop: threading.Event | None = None,
            split_size: int = 0, split_duration_s: float = 0.0, extra_outputs: dict | None = None,
            on_output=None, on_pass=None, image_compression=None) -> RunResult:
    """Replay ``bag_path`` through the graph for ``rig``; see the module docstring.

    Args:
        bag_path: input bag with ``<ns>/left/image_raw`` and ``<ns>/right/image_raw``
            (after ``remap``), or only their ``/compressed`` topics (:func:`open_input_bag`).
        rig: the rig of the cameras that recorded it.
        rate: playback speed (1 = recorded timing, 0 = as fast as the graph goes).
        record: output bag path for the graph's outputs, an open
            :class:`~canopy_stereo.bag.BagWriter` to append to (left open), or None.
        options: graph options (namespace, matcher, segmentation, ...).
        domain_id: DDS domain (default: a private one derived from the pid).
        max_in_flight: frames inside the graph at once when ``rate == 0``.
        idle_s: a frame missing after the graph has been idle this long is dropped.
        timeout_s: give up waiting for any single frame after this long.
        keep: output topics whose messages are returned in :attr:`RunResult.outputs`
            (names relative to the namespace, e.g. ``"points2"``).
        remap: bag topic -> topic to publish it on (a bag with one raw stereo pair under
            another namespace is remapped into ``options.namespace`` without it:
            :func:`stereo_input_remap`).
        progress: optional ``f(frames_out)`` callback per cloud.
        compression: chunk compression of the output bag (lz4 keeps up with the graph;
            zstd is smaller but costs about 20 ms per megabyte of output on this machine).
        context: an initialised rclpy context to build the graph in (default: a
            private one on ``domain_id``, shut down at the end).
        loop: play the bag again at its end, until ``stop`` is set (the graph is built once).
        stop: event that ends playback early (the frames in flight are still awaited).
        on_pass: with ``loop``, ``f(passes_done, frames_in, frames_out)`` at the end of each pass
            (counts so far; frames of the last pass may still be in flight).
        split_size, split_duration_s: split the recording into ``<name>_0.mcap``, ... by
            size (bytes) or log-time span (s), as rosbag2 does (0 = never).
        extra_outputs: further graph topics to receive (relative name -> message class,
            e.g. ``{"left/image_rect_color": Image}``); recorded and kept like the others.
        on_output: optional ``f(relative topic, stamp_ns, CDR bytes)`` called for every
            output message as it arrives (from the receiving thread; keep it short), e.g.
            to stream the graph to a viewer.
        image_compression: a :class:`~canopy_stereo.ros.compressed.RecordingCompression` to
            record the image outputs compressed (``<topic>/compressed``; masks as PNG, depth
            raw), or None.
    """
    options = options or GraphOptions()
    if rate < 0:
        raise CanopyStereoError(f"rate must be >= 0, got {rate}")
    if max_in_flight < 1:
        raise CanopyStereoError(f"max_in_flight must be >= 1, got {max_in_flight}")
    bag, play_topics, in_left = open_input_bag(bag_path, namespace=options.namespace, remap=remap)
    remap = stereo_input_remap(bag.topics, namespace=options.namespace, remap=remap)
    options = _with_transport(options, input_transport(in_left))
    ns = "/" + options.namespace.strip("/") if options.namespace.strip("/") else ""
    left_topics = {t for t in play_topics if remap.get(t, t) == in_left}
    outputs = {**options.output_topics(), **(extra_outputs or {})}
    result = RunResult(truncated=bag.truncated, problem=bag.problem,
                       outputs={k: [] for k in keep})
    book = _FrameBook()
    own_writer = record is not None and not isinstance(record, BagWriter)
    # the recording carries its rig (the one rig record every recorder writes), so that `view`,
    # `batch` and `run` measure and place it without --rig
    writer = (BagWriter(record, compression=compression, split_size=split_size,
                        split_duration_s=split_duration_s, metadata=recording_metadata(rig=rig))
              if own_writer else record)
    try:
        _run(bag, rig, rate, options, domain_id, max_in_flight, idle_s, timeout_s, remap, startup_timeout_s,
             progress, context, play_topics, left_topics, ns, outputs, result, book, writer, loop, stop,
             on_output, on_pass, image_compression)
    finally:
        if own_writer:
            result.recorded = writer.close()
        elif writer is not None:
            result.recorded = writer.path
        if writer is not None:
            result.recorded_files = list(writer.paths)
    result.truncated, result.problem = bag.truncated, bag.problem
    result.damage = [d.describe(bag.path).split(": ", 1)[1] for d in bag.damage]
    if book.frames_in == 0 and (result.invalid_messages or bag.truncated or bag.damage):
        why = (f"{len(result.invalid_messages)} input messages are not valid CDR (first: "
               f"{result.invalid_messages[0]})" if result.invalid_messages else
               f"the bag is {'truncated' if bag.truncated else 'damaged'} ({bag.problem})")
        raise BagError(f"{bag.path}: no frame could be played: {why}")
    result.frames_in, result.frames_out = book.frames_in, book.frames_out
    result.frames_dropped = book.dropped + len(book.in_flight)
    result.latencies_s = list(book.latencies)
    result.completed_at_s = list(book.out_times)
    if book.first_pub is not None and book.last_out is not None:
        result.wall_s = book.last_out - book.first_pub
    return result


#: Quiet time (s) awaited after the last cloud before the graph is torn down.
OUTPUT_DRAIN_S = 0.2


def _hold_every_frame(options: GraphOptions, rate: float, max_in_flight: int) -> GraphOptions:
    """As fast as possible (``rate`` 0) the player keeps ``max_in_flight`` frames in the graph and
    none may be dropped: rectify_node and disparity_node may hold that many waiting (unless set
    explicitly; their default of 1 is for cameras, which do not wait)."""
    if rate != 0:
        return options
    params = dict(options.node_parameters)
    for name in _WAITING_NODES:
        values = params.get(name, {})
        if "waiting_pairs" not in values:
            params[name] = {**values, "waiting_pairs": int(max_in_flight)}
    return replace(options, node_parameters=params)


#: Nodes whose slow stage keeps only the newest ``waiting_pairs`` pairs waiting.
_WAITING_NODES = ("rectify_node", "disparity_node")


def _run(bag, rig, rate, options, domain_id, max_in_flight, idle_s, timeout_s, remap, startup_timeout_s,
         progress, context, play_topics, left_topics, ns, outputs, result, book, writer, loop=False,
         stop=None, on_output_cb=None, on_pass=None, compression=None) -> None:
    """Build the graph, play, drain and tear down (the body of :func:`run_bag`)."""
    reliability = options.reliability
    options = _hold_every_frame(options, rate, max_in_flight)
    with (_given(context) if context is not None else ros_context(domain_id)) as ctx:
        graph = CanopyGraph(rig, ctx, options)
        io_node = CanopyNode("canopy_run", context=ctx, namespace=ns or "/",
                             start_parameter_services=False)
        tf_transforms = graph.nodes["rectify_node"].tf_transforms
        if writer is not None and tf_transforms:  # the rig's frames in the bag (REP 105 /tf_static)
            from canopy_stereo.ros.tf import write_static_transforms

            write_static_transforms(writer, tf_transforms, time.time_ns())
        try:
            def on_output(rel: str, data: bytes) -> None:
                now = time.monotonic()
                stamp = header_stamp_from_cdr(bytes(data)) if rel in stamped else None
                if writer is not None:
                    topic, tname, stored = f"{ns}/{rel}", type_name(outputs[rel]), bytes(data)
                    if compression is not None:
                        topic, tname, stored = compression.convert(topic, tname, stored)
                        if topic not in writer.topics:
                            writer.add_topic(topic, tname, qos_yaml=qos_profiles_yaml(reliability))
                    writer.write(topic, stored, time.time_ns(), publish_time_ns=stamp, msg_type=tname)
                if rel in result.outputs:
                    result.outputs[rel].append((stamp, bytes(data)))
                if on_output_cb is not None and stamp is not None:
                    on_output_cb(rel, stamp, bytes(data))
                if rel == "points2" and stamp is not None:
                    book.completed(stamp, now)
                    if progress is not None:
                        progress(book.frames_out)

            stamped = {rel for rel, cls in outputs.items() if has_header(cls)}  # traits: no header
            for rel, cls in outputs.items():
                if writer is not None and (compression is None or type_name(cls) != IMAGE_TYPE):
                    writer.add_topic(f"{ns}/{rel}", type_name(cls), qos_yaml=qos_profiles_yaml(reliability))
                io_node.create_subscription(cls, f"{ns}/{rel}",
                                            io_node.guarded(lambda d, r=rel: on_output(r, d)),
                                            recording_qos(50, reliability), raw=True)
            player = BagPlayer(io_node, bag, rate, loop=loop, remap=remap, topics=play_topics, depth=5)
            graph.add_node(io_node)
            graph.spin_in_background()
            _wait_connected(graph, io_node, player, startup_timeout_s)

            def graph_idle_for(seconds: float) -> bool:
                """No node has run a callback, and no frame moved, for ``seconds``."""
                return (all(n.idle_for() >= seconds for n in graph.nodes.values())
                        and time.monotonic() - book.last_activity >= seconds)

            def before_publish(m) -> bool:
                try:
                    m.decode()  # a message that is not valid CDR never reaches the nodes
                except BagError as exc:
                    result.invalid_messages.append(str(exc))
                    return False
                if m.topic not in left_topics or rate > 0:
                    return True
                deadline = time.monotonic() + timeout_s
                with book.cond:
                    while len(book.in_flight) >= max_in_flight and not (stop is not None and stop.is_set()):
                        book.cond.wait(0.05)
                        if len(book.in_flight) < max_in_flight:
                            break
                        if time.monotonic() >= deadline or graph_idle_for(idle_s):
                            book.drop_oldest()  # the condition's lock is re-entrant
                            deadline = time.monotonic() + timeout_s
                return True

            def on_published(m, t) -> None:
                stamp = header_stamp_from_cdr(m.data)
                if stamp is not None:
                    book.published(m.topic in left_topics, stamp, t)

            player.play(stop=stop, before_publish=before_publish, on_published=on_published,
                        on_pass=None if on_pass is None else
                        (lambda n: on_pass(n, book.frames_in, book.frames_out)))
            start_wait = time.monotonic()
            while book.in_flight:
                if time.monotonic() - start_wait > timeout_s or graph_idle_for(idle_s):
                    book.drop_oldest()
                    start_wait = time.monotonic()
                    continue
                with book.cond:
                    book.cond.wait(0.05)
            # the last frame's other outputs (depth, camera_info, mask) travel on their own
            # topics and may be taken after its points2: let the graph go quiet before the
            # recording is closed, so that every output of a completed frame is in the bag; a node
            # still working on one (a slow mask) is waited for, up to timeout_s, unless stopped
            wait_for(lambda: graph_idle_for(OUTPUT_DRAIN_S) or (stop is not None and stop.is_set()),
                     max(timeout_s, OUTPUT_DRAIN_S))
        finally:
            result.graph_stats = graph.stats()
            graph.shutdown()
            io_node.destroy_node()
            if io_node.drops:
                result.graph_stats["canopy_run"] = io_node.stats()


@contextmanager
def _given(context):
    yield context


def _wait_connected(graph: CanopyGraph, io_node, player: BagPlayer, timeout_s: float) -> None:
    """Wait until every publisher in the process is matched with its in-process subscribers."""
    nodes = list(graph.nodes.values()) + [io_node]
    wanted: dict[str, int] = {}
    for node in nodes:
        for sub in node.subscriptions:
            wanted[sub.topic_name] = wanted.get(sub.topic_name, 0) + 1
    pubs = [(p, wanted[p.topic_name]) for node in nodes for p in node.publishers
            if p.topic_name in wanted]
    offered: dict[str, int] = {}
    for p, _ in pubs:
        offered[p.topic_name] = offered.get(p.topic_name, 0) + 1
    subs = [(s, offered[s.topic_name]) for node in nodes for s in node.subscriptions
            if s.topic_name in offered]

    def ready() -> bool:  # matched on both sides, so that no first message is lost
        return (all(p.get_subscription_count() >= n for p, n in pubs)
                and all(s.get_publisher_count() >= n for s, n in subs))

    if not wait_for(ready, timeout_s) or not wait_for_subscribers(player.publishers.values(), 1.0):
        missing = sorted({p.topic_name for p, n in pubs if p.get_subscription_count() < n})
        raise CanopyStereoError(f"the node graph did not connect within {timeout_s:g} s "
                                f"(unmatched: {', '.join(missing) or 'bag topics'})")
