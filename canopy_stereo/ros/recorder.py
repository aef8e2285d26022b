"""Recording topics to a bag (``bag_record``).

:class:`BagRecorder` is a node that subscribes to topics with raw (serialized)
callbacks and appends the CDR bytes to a :class:`~canopy_stereo.bag.BagWriter`
with the reception time as log time. With ``all_topics`` it discovers topics
as they appear. Its subscription QoS follows the publishers (best effort if
any publisher of the topic is), keep last ``depth``.

The bag stays valid whatever ends the recording: ``bag_record`` closes it on
Ctrl-C (SIGINT), SIGTERM and SIGHUP, and the chunks are flushed and fsynced
every second, so even a killed recorder (SIGKILL, power loss) leaves a file
that :class:`~canopy_stereo.bag.BagReader` reads up to the last second
(and ``canopy-stereo bag repair`` completes).

``bag_record -o OUT.mcap TOPIC ... | --all [--namespace NS] [--metadata KEY=VALUE ...] [--rig RIG.yaml]
[--split-size BYTES] [--split-duration S]``: with splitting the files are ``OUT_0.mcap``,
``OUT_1.mcap``, ... (rosbag2's naming). The metadata pairs (plant_id, plot, treatment,
date, ...) and the rig file are written at the start of the bag (and of every split file)
as MCAP metadata records (:mod:`canopy_stereo.bag.metadata`), so the bag describes
itself (``canopy-stereo batch`` reads them). ``--compress-images [--jpeg-quality Q]`` stores
every 8-bit ``sensor_msgs/Image`` topic as image_transport's ``<topic>/compressed``
(``CompressedImage``: JPEG at Q, default 95; PNG for masks), about ten times smaller; depth
images stay raw (:class:`~canopy_stereo.ros.compressed.RecordingCompression`).
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from rclpy.node import Node
from rclpy.qos import ReliabilityPolicy

from canopy_stereo.bag import BagWriter
from canopy_stereo.bag.messages import qos_profiles_yaml
from canopy_stereo.bag.msgdefs import message_class, type_name
from canopy_stereo.bag.split import add_split_arguments, split_options
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.compressed_image import IMAGE_TYPE, add_compression_arguments
from canopy_stereo.ros.compressed import compression_from_args
from canopy_stereo.ros.qos import recording_qos

#: Topics never recorded by ``--all`` (ROS internals).
IGNORED_TOPICS = ("/rosout", "/parameter_events")


def header_stamp_from_cdr(data: bytes) -> int | None:
    """Header stamp (ns) of a serialized message that starts with ``std_msgs/Header``.

    CDR layout: 4-byte encapsulation (``00 01`` little-endian), then ``int32 sec``,
    ``uint32 nanosec``. Returns None for data too short or of unknown encoding.
    """
    if len(data) < 12 or data[0] != 0 or data[1] not in (0, 1):
        return None
    order = "little" if data[1] == 1 else "big"
    sec = int.from_bytes(data[4:8], order, signed=True)
    nsec = int.from_bytes(data[8:12], order, signed=False)
    return sec * 1_000_000_000 + nsec


def has_header(msg_class) -> bool:
    """True when messages of ``msg_class`` start with a ``std_msgs/Header`` (a ``std_msgs/String`` or a
    ``MarkerArray`` does not: their publish time is the log time, not bytes read as a stamp)."""
    fields = msg_class.get_fields_and_field_types()
    return next(iter(fields.items()), ("", ""))[1] == "std_msgs/Header"


class BagRecorder(Node):
    """Record topics into ``writer`` (see module docstring).

    Args:
        writer: an open :class:`BagWriter` (closed by :meth:`close`).
        topics: topic names (absolute, or relative to the node namespace).
        all_topics: also record every topic that appears (checked each second).
        depth: subscription queue depth.
        flush_period_s: how often completed chunks are written out (0 = never).
        on_message: optional ``f(topic, data, log_time_ns)`` called for each message.
        static_transforms: ``[(parent, child, T), ...]`` written at once on ``/tf_static``
            (:func:`canopy_stereo.ros.tf.write_static_transforms`). Otherwise, unless
            ``/tf_static`` itself is recorded, the transforms of every ``stereo_geometry``
            topic that appears (a rectify_node's) are written there: a bag always has them.
        compression: a :class:`~canopy_stereo.ros.compressed.RecordingCompression` to store
            images compressed, or None (as received).
    """

    def __init__(self, writer: BagWriter, topics=(), all_topics: bool = False, depth: int = 50,
                 flush_period_s: float = 1.0, on_message=None, node_name: str = "bag_recorder",
                 static_transforms=None, compression=None, **kwargs):
        super().__init__(node_name, **kwargs)
        self.compression = compression
        self._qos_yaml: dict[str, str] = {}
        self._geometry_subs = {}
        self._tf_written = static_transforms is not None
        self.writer = writer
        self.depth = int(depth)
        self.all_topics = bool(all_topics)
        self.on_message = on_message
        self.subscriptions_by_topic = {}
        self.received = {}
        self._lock = threading.Lock()
        self._pending = [self.resolve_topic_name(t) for t in topics]
        if static_transforms:  # [] (publish_tf false: the robot owns the frames): none written
            from canopy_stereo.ros.tf import write_static_transforms

            write_static_transforms(writer, static_transforms, time.time_ns())
        self._try_subscribe()
        self._timer = self.create_timer(0.2, self._try_subscribe)
        if flush_period_s > 0:
            self._flush_timer = self.create_timer(flush_period_s, self.writer.flush)

    def _publisher_reliability(self, topic: str) -> str:
        infos = self.get_publishers_info_by_topic(topic)
        if any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos):
            return "best_effort"
        return "reliable"

    def _try_subscribe(self) -> None:
        """Subscribe to pending topics whose type is known (from the ROS graph)."""
        known = dict(self.get_topic_names_and_types())
        self._watch_geometry(known)
        if self.all_topics:
            for name in known:
                if name not in IGNORED_TOPICS and name not in self.subscriptions_by_topic \
                        and name not in self._pending:
                    self._pending.append(name)
        for topic in list(self._pending):
            types = known.get(topic)
            if not types:
                continue
            try:
                cls = message_class(types[0])
            except CanopyStereoError as exc:
                self.get_logger().warning(f"not recording {topic}: {exc}")
                self._pending.remove(topic)
                continue
            self.add_topic(topic, cls, reliability=self._publisher_reliability(topic))

    def _watch_geometry(self, known: dict) -> None:
        """Subscribe (latched) to rectify_nodes' ``stereo_geometry`` to write /tf_static."""
        if self._tf_written or "/tf_static" in self.subscriptions_by_topic or "/tf_static" in self._pending:
            return
        from std_msgs.msg import String

        from canopy_stereo.ros.tf import latched_qos

        for name, types in known.items():
            if name.endswith("/stereo_geometry") and "std_msgs/msg/String" in types \
                    and name not in self._geometry_subs:
                self._geometry_subs[name] = self.create_subscription(
                    String, name, self._on_geometry, latched_qos())

    def _on_geometry(self, msg) -> None:
        from canopy_stereo.ros.stereo_geometry import parse_stereo_geometry
        from canopy_stereo.ros.tf import write_static_transforms

        if self._tf_written:
            return
        try:
            g = parse_stereo_geometry(msg)
        except CanopyStereoError as exc:
            self.get_logger().warning(f"stereo_geometry ignored: {exc}")
            return
        write_static_transforms(self.writer, [(p, c, T) for c, (p, T) in g.transforms.items()],
                                time.time_ns())
        self._tf_written = True

    def add_topic(self, topic: str, msg_class, *, reliability: str = "reliable") -> None:
        """Start recording ``topic`` of type ``msg_class`` now (no graph lookup)."""
        topic = self.resolve_topic_name(topic)
        with self._lock:
            if topic in self.subscriptions_by_topic:
                return
            if topic in self._pending:
                self._pending.remove(topic)
            tname = type_name(msg_class)
            self._qos_yaml[topic] = qos_profiles_yaml(reliability)
            if self.compression is None or tname != IMAGE_TYPE:  # images: declared as they are stored
                self.writer.add_topic(topic, tname, qos_yaml=self._qos_yaml[topic])
            self.received[topic] = 0
            stamped = has_header(msg_class)
            self.subscriptions_by_topic[topic] = self.create_subscription(
                msg_class, topic, lambda data, t=topic, n=tname, h=stamped: self._on_message(t, n, data, h),
                recording_qos(self.depth, reliability), raw=True)
        self.get_logger().info(f"recording {topic} ({tname}, {reliability})")

    def _on_message(self, topic: str, tname: str, data: bytes, stamped: bool = True) -> None:
        now = time.time_ns()
        stamp = header_stamp_from_cdr(data) if stamped else None
        if self.compression is not None:
            out_topic, out_type, out = self.compression.convert(topic, tname, data)
            if out_topic not in self.writer.topics:
                self.writer.add_topic(out_topic, out_type, qos_yaml=self._qos_yaml.get(topic))
            self.writer.write(out_topic, out, now, publish_time_ns=stamp, msg_type=out_type)
        else:
            self.writer.write(topic, data, now, publish_time_ns=stamp, msg_type=tname)
        with self._lock:
            self.received[topic] += 1
        if self.on_message is not None:
            self.on_message(topic, data, now)

    def close(self):
        """Stop recording and close the bag (valid file)."""
        for sub in list(self.subscriptions_by_topic.values()):
            self.destroy_subscription(sub)
        self.subscriptions_by_topic.clear()
        return self.writer.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bag_record", description="Record topics to a rosbag2 MCAP file.")
    p.add_argument("topics", nargs="*", help="topics to record")
    p.add_argument("-o", "--output", required=True, help="output bag (.mcap)")
    p.add_argument("-a", "--all", action="store_true", help="record every topic that appears")
    p.add_argument("--compression", default="zstd", choices=("zstd", "lz4", "none"))
    p.add_argument("--max-duration", type=float, default=0.0, metavar="S",
                   help="stop after S seconds (0 = until Ctrl-C/SIGTERM/SIGHUP)")
    add_split_arguments(p)
    p.add_argument("--metadata", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                   help="describe the recording (plant_id=A12 plot=row1 treatment=dry date=2026-05-04 ...): "
                        "stored in the bag's 'canopy_stereo' metadata record")
    p.add_argument("--rig", metavar="RIG.yaml",
                   help="rig file of the cameras, stored in the bag's 'canopy_stereo_rig' metadata record")
    add_compression_arguments(p)
    return p



def main(args=None) -> int:
    """``bag_record`` executable; SIGINT/SIGTERM/SIGHUP end the recording with a valid file."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    from canopy_stereo.ros.context import init_executable_ros, parse_executable_args

    argv = sys.argv if args is None else args
    opts = parse_executable_args("bag_record", build_parser(), argv)
    if opts is None:
        return 2
    if not opts.topics and not opts.all:
        print("bag_record: error: name topics to record or use --all", file=sys.stderr)
        return 2
    stop = threading.Event()
    if not init_executable_ros("bag_record", argv):  # a bad --params-file or --ros-args: one line
        return 2
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):  # finish the file, then exit
        signal.signal(sig, lambda *_: stop.set())
    recorder = None
    status = 0
    try:
        from canopy_stereo.bag.metadata import parse_key_values, recording_metadata
        from canopy_stereo.io.rig import load_rig

        records = recording_metadata(parse_key_values(opts.metadata),
                                     load_rig(opts.rig) if opts.rig else None)
        writer = BagWriter(opts.output, compression=opts.compression, metadata=records,
                           **split_options(opts))
        recorder = BagRecorder(writer, opts.topics, all_topics=opts.all, compression=compression_from_args(opts))
        executor = SingleThreadedExecutor()
        executor.add_node(recorder)
        deadline = time.monotonic() + opts.max_duration if opts.max_duration > 0 else None
        print(f"bag_record: recording to {opts.output}", file=sys.stderr, flush=True)
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
            if deadline is not None and time.monotonic() >= deadline:
                break
    except CanopyStereoError as exc:
        print(f"bag_record: error: {exc}", file=sys.stderr)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if recorder is not None:
            try:
                recorder.close()
            except CanopyStereoError as exc:  # the disk filled up: closing fails the same way
                if status == 0:
                    print(f"bag_record: error: {exc}", file=sys.stderr)
                status = 2
            else:
                counts = ", ".join(f"{t}: {n}" for t, n in recorder.received.items())
                files = ", ".join(str(p) for p in recorder.writer.paths)
                print(f"bag_record: wrote {files} ({counts or 'no messages'})", file=sys.stderr)
            recorder.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return status
