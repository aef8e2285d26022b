"""rosbag2-compatible MCAP bags, written and read with the ``mcap`` package.

Files follow what rosbag2's MCAP storage plugin writes, so ``ros2 bag play``,
``ros2 bag info``, ``rosbags`` and Foxglove read them:

* header profile ``ros2``; one schema per message type with encoding
  ``ros2msg`` and the full definition text (:mod:`~canopy_stereo.ros.msgdefs`);
* one channel per topic with message encoding ``cdr`` and the channel metadata
  ``offered_qos_profiles`` (YAML, rosbag2 format version 9);
* messages serialized by ``rclpy.serialization`` (CDR with encapsulation header),
  ``log_time`` = reception time, ``publish_time`` = header stamp (or log time);
* chunked, zstd-compressed by default, with message indexes, statistics and
  summary offsets; a ``rosbag2`` metadata record holding the bag information;
* optional further metadata records (``metadata=`` / :meth:`BagWriter.add_metadata`),
  written as soon as they are given so that a recording cut short keeps them
  (canopy_stereo's own: :mod:`canopy_stereo.io.bag_metadata`); the pairs of the
  ``canopy_stereo`` record are also rosbag2's ``custom_data`` (what ``ros2 bag
  record --custom-data`` writes), for tools that know only rosbag2.

:class:`BagReader` reads such files, and also ones cut short (a recorder killed
before it could finish): it then scans the file linearly, yields every message
up to the damage and reports ``truncated = True`` with the reason.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator, NamedTuple

import yaml
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.bag_metadata import METADATA_RECORD
from canopy_stereo.ros.msgdefs import message_class, message_definition, type_name

_MAGIC = b"\x89MCAP0\r\n"
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


class BagError(CanopyStereoError):
    """A bag file cannot be read or written."""


def qos_profiles_yaml(reliability: str = "reliable", depth: int = 1,
                      durability: str = "volatile") -> str:
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
        """The deserialized ROS message."""
        from rclpy.serialization import deserialize_message

        return deserialize_message(self.data, message_class(self.type_name))


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


class BagWriter:
    """Write a rosbag2-compatible MCAP file (thread-safe).

    Use as a context manager, or call :meth:`close`; the file is valid only
    once closed (:class:`BagReader` still recovers the completed chunks of an
    unclosed file).

    Args:
        path: output ``.mcap`` file (parent folders are created).
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"`` chunk compression.
        chunk_size: uncompressed bytes per chunk.
        overwrite: replace an existing file (otherwise :class:`BagError`).
        metadata: optional ``{record name: {key: value}}`` MCAP metadata records
            (strings) written at once (see :meth:`add_metadata`).
    """

    def __init__(self, path, compression: str = "zstd", chunk_size: int = 1 << 20,
                 overwrite: bool = True, metadata: dict | None = None):
        self.path = Path(path)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE, "": CompressionType.NONE}
        if compression not in comp:
            raise BagError(f"unknown bag compression {compression!r}; use zstd, lz4 or none")
        if self.path.exists() and not overwrite:
            raise BagError(f"{self.path} exists (choose another name)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._file = open(self.path, "wb")
        except OSError as exc:
            raise BagError(f"cannot write bag {self.path}: {exc.strerror or exc}") from None
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=comp[compression])
        self._writer.start(profile="ros2", library="canopy_stereo")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.topics: dict[str, TopicInfo] = {}
        self._lock = threading.Lock()
        self._start_ns: int | None = None
        self._end_ns = 0
        self.message_count = 0
        self.closed = False
        self.custom_data: dict[str, str] = {}
        for name, data in (metadata or {}).items():
            self.add_metadata(name, data)

    def add_metadata(self, name: str, data: dict) -> None:
        """Write an MCAP metadata record ``name`` holding ``data`` (str -> str; other
        values are converted with ``str``). It goes into the file at once, so a
        recording cut short keeps it. ``rosbag2`` is reserved for the bag information."""
        if not name or name == "rosbag2":
            raise BagError(f"metadata record name {name!r} is reserved or empty")
        record = {str(k): str(v) for k, v in dict(data).items()}
        with self._lock:
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            self._writer.add_metadata(name, record)
            if name == METADATA_RECORD:
                self.custom_data.update(record)

    def add_topic(self, topic: str, msg_type: str, qos_yaml: str | None = None) -> None:
        """Declare ``topic`` with type ``msg_type`` (``"sensor_msgs/msg/Image"``)."""
        with self._lock:
            self._add_topic(topic, msg_type, qos_yaml)

    def _add_topic(self, topic, msg_type, qos_yaml=None):
        if topic in self._channels:
            if self.topics[topic].type_name != msg_type:
                raise BagError(f"topic {topic} already has type {self.topics[topic].type_name}")
            return
        msg_type = type_name(message_class(msg_type))
        if msg_type not in self._schemas:
            self._schemas[msg_type] = self._writer.register_schema(
                name=msg_type, encoding="ros2msg", data=message_definition(msg_type).encode())
        qos_yaml = qos_yaml if qos_yaml is not None else qos_profiles_yaml()
        self._channels[topic] = self._writer.register_channel(
            topic=topic, message_encoding="cdr", schema_id=self._schemas[msg_type],
            metadata={"offered_qos_profiles": qos_yaml})
        self.topics[topic] = TopicInfo(topic, msg_type, 0, message_definition(msg_type), qos_yaml)

    def write(self, topic: str, msg, log_time_ns: int, publish_time_ns: int | None = None,
              msg_type: str | None = None) -> None:
        """Append one message (a ROS message, or CDR bytes with ``msg_type``)."""
        if isinstance(msg, (bytes, bytearray, memoryview)):
            if msg_type is None and topic not in self.topics:
                raise BagError(f"serialized data for new topic {topic} needs msg_type")
            data = bytes(msg)
        else:
            from rclpy.serialization import serialize_message

            msg_type = msg_type or type_name(msg)
            data = serialize_message(msg)
            if publish_time_ns is None:
                publish_time_ns = _stamp_of(msg)
        log_time_ns = int(log_time_ns)
        publish_time_ns = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        with self._lock:
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            if topic not in self._channels:
                self._add_topic(topic, msg_type)
            info = self.topics[topic]
            self._writer.add_message(channel_id=self._channels[topic], log_time=log_time_ns,
                                     data=data, publish_time=publish_time_ns,
                                     sequence=info.message_count)
            info.message_count += 1
            self.message_count += 1
            self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
            self._end_ns = max(self._end_ns, log_time_ns)

    def _bag_information(self) -> str:
        start = self._start_ns or 0
        duration = (self._end_ns - start) if self.message_count else 0
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.message_count,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type_name,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos_yaml,
                                    "type_description_hash": ""},
                 "message_count": t.message_count}
                for t in self.topics.values()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": self.message_count}],
            "custom_data": dict(self.custom_data),
            "ros_distro": "jazzy",
        }
        return yaml.safe_dump(info, sort_keys=False)

    def flush(self) -> None:
        """Write the chunk in progress to disk: a process killed later keeps everything
        written so far (readable as a truncated bag)."""
        with self._lock:
            if not self.closed:
                self._writer.flush()

    def close(self) -> Path:
        """Write the summary and footer and close the file (idempotent)."""
        with self._lock:
            if self.closed:
                return self.path
            self.closed = True
            self._writer.add_metadata("rosbag2", {"serialized_metadata": self._bag_information()})
            self._writer.finish()
            self._file.close()
        return self.path

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


@dataclass
class _Index:
    schemas: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None


class BagReader:
    """Read a rosbag2 MCAP file (complete or truncated).

    Attributes:
        path: the file.
        topics: topic -> :class:`TopicInfo`.
        message_count, start_ns, end_ns: totals and log-time range (ns).
        truncated: the file ends early (no valid summary/footer); messages up to
            the damage are still readable.
        problem: what was wrong with a truncated file ("" otherwise).
    """

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.is_file():
            raise BagError(f"bag not found: {self.path}")
        with open(self.path, "rb") as f:
            magic = f.read(8)
        if magic != _MAGIC:
            raise BagError(f"{self.path} is not an MCAP file (bad magic)")
        self.truncated = False
        self.problem = ""
        self._summary = None
        self._scanned_metadata: list = []
        try:
            with open(self.path, "rb") as f:
                summary = SeekingReader(f).get_summary()
            if summary is not None and summary.statistics is not None:
                self._summary = summary
        except Exception:  # noqa: BLE001 - a damaged footer raises many types; scan instead
            self._summary = None
        if self._summary is not None:
            idx = _Index(schemas=dict(self._summary.schemas), channels=dict(self._summary.channels),
                         counts=dict(self._summary.statistics.channel_message_counts),
                         start_ns=self._summary.statistics.message_start_time,
                         end_ns=self._summary.statistics.message_end_time)
        else:
            idx = self._scan()
        self._check_profile()
        self.topics: dict[str, TopicInfo] = {}
        self._channel_types: dict[int, str] = {}
        for cid, ch in idx.channels.items():
            schema = idx.schemas.get(ch.schema_id)
            if schema is None:
                raise BagError(f"{self.path}: channel {ch.topic} has no schema")
            if ch.message_encoding != "cdr":
                raise BagError(f"{self.path}: topic {ch.topic} is {ch.message_encoding}, not cdr")
            tname = schema.name if schema.name.count("/") == 2 else schema.name.replace("/", "/msg/", 1)
            self._channel_types[cid] = tname
            info = self.topics.setdefault(ch.topic, TopicInfo(
                ch.topic, tname, 0, schema.data.decode("utf-8", "replace"),
                ch.metadata.get("offered_qos_profiles", "")))
            info.message_count += int(idx.counts.get(cid, 0))
        self.message_count = sum(t.message_count for t in self.topics.values())
        self.start_ns = idx.start_ns or 0
        self.end_ns = idx.end_ns or 0

    def _check_profile(self):
        with open(self.path, "rb") as f:
            try:
                header = next(iter(StreamReader(f, skip_magic=False).records))
            except (McapError, StopIteration, ValueError, EOFError) as exc:
                raise BagError(f"{self.path}: unreadable MCAP header ({exc})") from None
        if getattr(header, "profile", "ros2") != "ros2":
            raise BagError(f"{self.path}: MCAP profile is {header.profile!r}, not ros2")

    def _records(self) -> Iterator:
        """Records of the file in order; stops quietly at damage (recorded in ``problem``)."""
        with open(self.path, "rb") as f:
            reader = StreamReader(f, skip_magic=False)
            try:
                yield from reader.records
            except Exception as exc:  # noqa: BLE001 - mcap, zstd and lz4 each raise their own types
                self.truncated = True
                if not self.problem:
                    self.problem = f"data ends in a damaged or incomplete record ({type(exc).__name__})"

    def _scan(self) -> _Index:
        idx = _Index()
        self.truncated = True
        for rec in self._records():
            if isinstance(rec, Schema):
                idx.schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                idx.channels[rec.id] = rec
            elif isinstance(rec, Metadata):
                self._scanned_metadata.append((rec.name, dict(rec.metadata)))
            elif isinstance(rec, Message):
                idx.counts[rec.channel_id] = idx.counts.get(rec.channel_id, 0) + 1
                idx.start_ns = rec.log_time if idx.start_ns is None else min(idx.start_ns, rec.log_time)
                idx.end_ns = rec.log_time if idx.end_ns is None else max(idx.end_ns, rec.log_time)
        if not self.problem:
            self.problem = "no summary section (the recorder did not close the file)"
        return idx

    def messages(self, topics=None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[BagMessage]:
        """Serialized messages in log-time order (file order for a truncated bag).

        Args:
            topics: topic names to keep (None: all).
            start_ns, end_ns: keep ``start_ns <= log_time < end_ns`` (absolute ns).
        """
        wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)

        def keep(topic, t):
            return ((wanted is None or topic in wanted) and (start_ns is None or t >= start_ns)
                    and (end_ns is None or t < end_ns))

        if self._summary is not None:
            with open(self.path, "rb") as f:
                for _, ch, msg in SeekingReader(f).iter_messages(log_time_order=True):
                    if keep(ch.topic, msg.log_time):
                        yield BagMessage(ch.topic, self._channel_types[ch.id], msg.log_time,
                                         msg.publish_time, bytes(msg.data))
            return
        channels = {}
        for rec in self._records():
            if isinstance(rec, Channel):
                channels[rec.id] = rec
            elif isinstance(rec, Message) and rec.channel_id in self._channel_types:
                ch = channels[rec.channel_id]
                if keep(ch.topic, rec.log_time):
                    yield BagMessage(ch.topic, self._channel_types[rec.channel_id], rec.log_time,
                                     rec.publish_time, bytes(rec.data))

    def metadata(self) -> dict[str, dict[str, str]]:
        """The file's MCAP metadata records, ``{name: {key: value}}`` (the ``rosbag2``
        record included when the file has one; a later record of the same name wins).
        A truncated file yields the records found before the damage."""
        if self._summary is None:
            return {name: dict(data) for name, data in self._scanned_metadata}
        out = {}
        with open(self.path, "rb") as f:
            for rec in SeekingReader(f).iter_metadata():
                out[rec.name] = dict(rec.metadata)
        return out

    def read(self, topics=None, start_ns=None, end_ns=None):
        """``(BagMessage, decoded message)`` pairs in log-time order."""
        for m in self.messages(topics, start_ns, end_ns):
            yield m, m.decode()

    def summary_text(self) -> str:
        """A short human-readable description (like ``ros2 bag info``)."""
        dur = (self.end_ns - self.start_ns) / 1e9 if self.message_count else 0.0
        lines = [f"bag: {self.path}", f"messages: {self.message_count}, duration: {dur:.3f} s"]
        if self.truncated:
            lines.append(f"TRUNCATED: {self.problem}")
        for t in sorted(self.topics.values(), key=lambda t: t.name):
            lines.append(f"  {t.name}  {t.type_name}  {t.message_count} msgs")
        return "\n".join(lines)
