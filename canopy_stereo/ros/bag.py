"""rosbag2-compatible MCAP bags, written and read with checks at every step.

Files follow what rosbag2's MCAP storage plugin writes, so ``ros2 bag play``,
``ros2 bag info``, ``rosbags`` and Foxglove read them:

* header profile ``ros2``; one schema per message type with encoding
  ``ros2msg`` and the full definition text (:mod:`~canopy_stereo.ros.msgdefs`);
* one channel per topic with message encoding ``cdr`` and the channel metadata
  ``offered_qos_profiles`` (YAML, rosbag2 format version 9);
* messages serialized by ``rclpy.serialization`` (CDR with encapsulation header),
  ``log_time`` = reception time, ``publish_time`` = header stamp (or log time);
* chunked, zstd-compressed by default, with chunk CRCs, a data-section CRC,
  message indexes, statistics and summary offsets; a ``rosbag2`` metadata
  record holding the bag information;
* optional further metadata records (``metadata=`` / :meth:`BagWriter.add_metadata`),
  written as soon as they are given (and again at the start of every split file) so
  that a recording cut short keeps them (canopy_stereo's own:
  :mod:`canopy_stereo.io.bag_metadata`); the pairs of the ``canopy_stereo`` record are
  also rosbag2's ``custom_data`` (what ``ros2 bag record --custom-data`` writes), for
  tools that know only rosbag2.

:class:`BagWriter` ends the chunk in progress and fsyncs the file every
``flush_period_s`` (1 s), so a recorder killed with SIGKILL (or a power cut)
loses at most the messages of the last second: the rest reads as a truncated
bag, and ``canopy-stereo bag repair`` turns it into a complete one. With
``split_size``/``split_duration_s`` it rotates to ``<name>_0.mcap``,
``<name>_1.mcap``, ... like rosbag2's bag splitting.

:class:`BagReader` never returns damaged data. It walks the record framing of
the file itself, checks every chunk's CRC (and size, compression, record
layout) before it yields a message of that chunk, and believes the summary
(topics, counts, times, chunk indexes) only when its CRC matches and it agrees
with the data actually found. A damaged chunk is reported
(:attr:`BagReader.damage`: byte offset, problem, messages lost) and skipped;
the chunks around it are still read (the reader resynchronises on the next
intact chunk). A file cut short (a recorder that never closed it) is read up to
the cut and says so (:attr:`BagReader.truncated`). Every failure is a
:class:`BagError` with one line naming the file, the byte offset and the problem.
"""
from __future__ import annotations

import _thread
import atexit
import heapq
import os
import queue
import re
import struct
import threading
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator, NamedTuple

import yaml
from mcap.writer import CompressionType, Writer

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.bag_metadata import METADATA_RECORD
from canopy_stereo.ros.msgdefs import message_class, message_definition, type_name

_MAGIC = b"\x89MCAP0\r\n"
_INFINITE = {"sec": 9223372036, "nsec": 854775807}


class BagError(CanopyStereoError):
    """A bag file cannot be read or written."""


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
        from rclpy.serialization import deserialize_message

        try:
            cls = message_class(self.type_name)
        except CanopyStereoError as exc:
            raise BagError(f"topic {self.topic}: {exc}") from None
        try:
            return deserialize_message(self.data, cls)
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


def _one_line(exc) -> str:
    text = " ".join(str(exc).split())
    return text[:200] if text else type(exc).__name__


def split_file_path(path, index: int) -> Path:
    """The ``index``-th file of a split recording: ``out.mcap`` -> ``out_<index>.mcap``
    (rosbag2 names split files ``<name>_0.mcap``, ``<name>_1.mcap``, ...)."""
    path = Path(path)
    suffix = path.suffix or ".mcap"
    return path.with_name(f"{path.stem if path.suffix else path.name}_{int(index)}{suffix}")


class BagWriter:
    """Write a rosbag2-compatible MCAP file (thread-safe), optionally split in several.

    Use as a context manager, or call :meth:`close`; a file is complete (summary
    and footer) only once closed. Until then the chunks are written out and
    fsynced every ``flush_period_s``, so a killed process loses at most that
    much: :class:`BagReader` reads the rest as a truncated bag.

    Args:
        path: output ``.mcap`` file (parent folders are created). With splitting
            the files are ``<stem>_0.mcap``, ``<stem>_1.mcap``, ... beside it.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"`` chunk compression.
        chunk_size: uncompressed bytes per chunk.
        overwrite: replace an existing file (otherwise :class:`BagError`).
        flush_period_s: end the chunk in progress and fsync at least this often
            (seconds; 0 = only when a chunk is full).
        split_size: start a new file when the current one reaches this many bytes
            (0 = never).
        split_duration_s: start a new file when the current one spans this many
            seconds of log time (0 = never).
        metadata: optional ``{record name: {key: value}}`` MCAP metadata records
            (strings) written at once (see :meth:`add_metadata`).
    """

    def __init__(self, path, compression: str = "zstd", chunk_size: int = 1 << 20,
                 overwrite: bool = True, metadata: dict | None = None, *,
                 flush_period_s: float = 1.0, split_size: int = 0,
                 split_duration_s: float = 0.0):
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE, "": CompressionType.NONE}
        if compression not in comp:
            raise BagError(f"unknown bag compression {compression!r}; use zstd, lz4 or none")
        if split_size < 0 or split_duration_s < 0 or flush_period_s < 0:
            raise BagError("split size, split duration and flush period must be >= 0")
        self.base_path = Path(path)
        self._compression = comp[compression]
        self._chunk_size = int(chunk_size)
        self._overwrite = bool(overwrite)
        self.split_size = int(split_size)
        self.split_duration_ns = int(round(split_duration_s * 1e9))
        self.splitting = self.split_size > 0 or self.split_duration_ns > 0
        self.paths: list[Path] = []
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._metadata: list[tuple[str, dict]] = []  # records written at the start of every file
        self.custom_data: dict[str, str] = {}  # rosbag2's custom_data: the canopy_stereo record
        self.topics: dict[str, TopicInfo] = {}
        self._lock = threading.RLock()
        self._start_ns: int | None = None
        self._end_ns = 0
        self.message_count = 0
        self.closed = False
        self._file = self._writer = None
        self._started = False
        self._flush_stop = threading.Event()
        self._flusher = None
        self._jobs = None
        # (a Ctrl-C/SIGTERM landing while the file is being created waits until the writer
        # is registered; interpreter exit then completes the file)
        _run_to_end(self._open_locked)
        if flush_period_s > 0:
            self._flusher = threading.Thread(target=self._flush_loop, args=(float(flush_period_s),),
                                             name=f"bag_flush:{self.base_path.name}", daemon=True)
            self._flusher.start()
        for name, data in (metadata or {}).items():
            self.add_metadata(name, data)

    # -- files -------------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The file being written (the last one once closed)."""
        return self.paths[-1]

    def _open_locked(self) -> None:
        with self._lock:
            self._open_next()

    def _rotate(self) -> None:
        self._finish_file()
        self._open_next()

    def _open_next(self) -> None:
        path = split_file_path(self.base_path, len(self.paths)) if self.splitting else self.base_path
        if path.exists() and not self._overwrite:
            raise BagError(f"{path} exists (choose another name)")
        self._schemas, self._channels = {}, {}
        self._file_counts: dict[str, int] = {}
        self._file_start_ns: int | None = None
        self._file_end_ns = 0
        self._file_messages = 0
        self._pending = 0
        self._dirty = False
        self._started = False
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._file = open(path, "wb")
        except OSError as exc:
            raise BagError(f"cannot write bag {path}: {exc.strerror or exc}") from None
        self.paths.append(path)
        _OPEN_WRITERS.add(self)  # from here on, interpreter exit completes the file
        self._writer = Writer(self._file, chunk_size=self._chunk_size, compression=self._compression,
                              enable_data_crcs=True)
        self._io(self._writer.start, profile="ros2", library="canopy_stereo")
        self._started = True
        for info in self.topics.values():
            self._register(info)
        for name, data in self._metadata:
            self._io(self._writer.add_metadata, name, data)

    def _io(self, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except OSError as exc:
            raise BagError(f"cannot write bag {self.path}: {exc.strerror or exc}") from None

    def _register(self, info: TopicInfo) -> None:
        if info.type_name not in self._schemas:
            self._schemas[info.type_name] = self._io(
                self._writer.register_schema, name=info.type_name, encoding="ros2msg",
                data=info.definition.encode())
        self._channels[info.name] = self._io(
            self._writer.register_channel, topic=info.name, message_encoding="cdr",
            schema_id=self._schemas[info.type_name], metadata={"offered_qos_profiles": info.qos_yaml})
        self._file_counts[info.name] = 0

    def _finish_file(self) -> None:
        if not self._started:  # interrupted while opening: make the file a valid empty bag
            self._file.seek(0)
            self._file.truncate()
            self._writer = Writer(self._file, compression=self._compression, enable_data_crcs=True)
            self._writer.start(profile="ros2", library="canopy_stereo")
            self._started = True
        self._io(self._writer.add_metadata, "rosbag2",
                 {"serialized_metadata": self._bag_information()})
        self._io(self._writer.finish)
        self._io(self._file.flush)
        try:
            os.fsync(self._file.fileno())
        except OSError:
            pass
        self._file.close()

    # -- writing -----------------------------------------------------------------------------

    def add_topic(self, topic: str, msg_type: str, *, qos_yaml: str | None = None,
                  definition: str | None = None) -> None:
        """Declare ``topic`` with type ``msg_type`` (``"sensor_msgs/msg/Image"``).

        ``definition``: the ``ros2msg`` schema text to store (default: the installed
        type's); with it the type need not be installed (copying foreign bags).
        """
        def add():
            with self._lock:
                self._add_topic(topic, msg_type, qos_yaml, definition)

        self._uninterrupted(add)

    def _add_topic(self, topic, msg_type, qos_yaml=None, definition=None):
        if topic in self.topics:
            if self.topics[topic].type_name not in (msg_type, _normal_type(msg_type)):
                raise BagError(f"topic {topic} already has type {self.topics[topic].type_name}")
            return
        if definition is None:
            msg_type = type_name(message_class(msg_type))
            definition = message_definition(msg_type)
        qos_yaml = qos_yaml if qos_yaml is not None else qos_profiles_yaml()
        info = TopicInfo(topic, msg_type, 0, definition, qos_yaml)
        self.topics[topic] = info
        self._register(info)

    def add_metadata(self, name: str, data: dict) -> None:
        """Write an MCAP metadata record ``name`` holding ``data`` (str -> str; other
        values are converted with ``str``). It goes into the current file at once, so a
        recording cut short keeps it, and into every later split file when it starts.
        ``rosbag2`` is reserved for the bag information."""
        if not name or name == "rosbag2":
            raise BagError(f"metadata record name {name!r} is reserved or empty")
        record = {str(k): str(v) for k, v in dict(data).items()}
        with self._lock:
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            self._metadata.append((str(name), record))
            self._io(self._writer.add_metadata, str(name), record)
            if name == METADATA_RECORD:
                self.custom_data.update(record)

    def write(self, topic: str, msg, log_time_ns: int, *, publish_time_ns: int | None = None,
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
        self._uninterrupted(self._append, topic, data, log_time_ns, publish_time_ns, msg_type)

    def _uninterrupted(self, fn, *args):
        """``fn(*args)``, from the main thread by way of the writer's own thread so that a
        Ctrl-C/SIGTERM (a KeyboardInterrupt there) cannot stop it half-way and leave the
        chunk in progress inconsistent; the interrupt is raised again afterwards. Other
        threads (ROS executors) never see KeyboardInterrupt and call ``fn`` directly."""
        if threading.current_thread() is not threading.main_thread():
            return fn(*args)
        if self._jobs is None:
            self._jobs = queue.SimpleQueue()
            _thread.start_new_thread(self._work, (self._jobs,))
        done = _thread.allocate_lock()
        done.acquire()
        box: list = []
        self._jobs.put((fn, args, done, box))
        return _wait_done(done, box)

    @staticmethod
    def _work(jobs) -> None:
        while True:
            job = jobs.get()
            if job is None:
                return
            fn, args, done, box = job
            _run_into(fn, args, done, box)

    def _append(self, topic, data, log_time_ns, publish_time_ns, msg_type) -> None:
        with self._lock:
            if self.closed:
                raise BagError(f"bag {self.path} is closed")
            if topic not in self.topics:
                self._add_topic(topic, msg_type)
            if self._file_messages and self._should_split(log_time_ns, len(data)):
                self._rotate()
            info = self.topics[topic]
            self._io(self._writer.add_message, channel_id=self._channels[topic], log_time=log_time_ns,
                     data=data, publish_time=publish_time_ns, sequence=info.message_count)
            self._pending += len(data) + 31
            if self._pending > self._chunk_size:
                self._pending = 0  # the writer ended the chunk
            self._dirty = True
            info.message_count += 1
            self.message_count += 1
            self._file_counts[topic] += 1
            self._file_messages += 1
            self._start_ns = log_time_ns if self._start_ns is None else min(self._start_ns, log_time_ns)
            self._end_ns = max(self._end_ns, log_time_ns)
            self._file_start_ns = (log_time_ns if self._file_start_ns is None
                                   else min(self._file_start_ns, log_time_ns))
            self._file_end_ns = max(self._file_end_ns, log_time_ns)

    def _should_split(self, log_time_ns: int, size: int) -> bool:
        if self.split_size and self._file.tell() + self._pending + size >= self.split_size:
            return True
        return bool(self.split_duration_ns and self._file_start_ns is not None
                    and log_time_ns - self._file_start_ns >= self.split_duration_ns)

    def _bag_information(self) -> str:
        start = self._file_start_ns or 0
        duration = (self._file_end_ns - start) if self._file_messages else 0
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self._file_messages,
            "topics_with_message_count": [
                {"topic_metadata": {"name": t.name, "type": t.type_name,
                                    "serialization_format": "cdr",
                                    "offered_qos_profiles": t.qos_yaml,
                                    "type_description_hash": ""},
                 "message_count": self._file_counts.get(t.name, 0)}
                for t in self.topics.values()],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.path.name],
            "files": [{"path": self.path.name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": duration}, "message_count": self._file_messages}],
            "custom_data": dict(self.custom_data),
            "ros_distro": "jazzy",
        }
        return yaml.safe_dump(info, sort_keys=False)

    def flush(self) -> None:
        """End the chunk in progress, write it out and fsync: a process killed later
        keeps everything written so far (readable as a truncated bag)."""
        with self._lock:
            if self.closed or not self._dirty:
                return
            self._io(self._writer.flush)
            self._pending = 0
            self._dirty = False
            fd = self._file.fileno()
        try:  # outside the lock: writers go on while the disk catches up
            os.fsync(fd)
        except OSError:
            pass

    def _flush_loop(self, period: float) -> None:
        while not self._flush_stop.wait(period):
            try:
                self.flush()
            except BagError:
                return  # the next write reports it

    def close(self) -> Path:
        """Write the summary and footer and close the file (idempotent).

        The closing work runs to its end even when a second Ctrl-C/SIGTERM arrives
        meanwhile (the interrupt is raised again afterwards): the file is complete."""
        if self.closed:
            return self.path
        self._flush_stop.set()
        _run_to_end(self._close_now)
        return self.path

    def _close_now(self) -> None:
        with self._lock:
            if self.closed:
                return
            self.closed = True
            _OPEN_WRITERS.discard(self)
            if self._jobs is not None:
                self._jobs.put(None)
            if self._file is not None:
                self._finish_file()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _run_into(fn, args, done, box) -> None:
    try:
        box.append((True, fn(*args)))
    except BaseException as exc:  # noqa: BLE001 - handed to the waiting caller
        box.append((False, exc))
    finally:
        done.release()


def _wait_done(done, box):
    """Wait (a KeyboardInterrupt meanwhile is held back) for a job; its result or exception."""
    interrupted = False
    while not box:  # (the job fills box before it releases done; an interrupt may land anywhere)
        try:
            done.acquire(timeout=0.05)
        except KeyboardInterrupt:
            interrupted = True
    ok, value = box[0]
    if not ok:
        raise value
    if interrupted:
        raise KeyboardInterrupt
    return value


def _run_to_end(fn, *args):
    """Run ``fn(*args)`` in a helper thread and wait for it: a KeyboardInterrupt (Ctrl-C, or
    SIGTERM/SIGHUP turned into one) arriving meanwhile cannot cut it short; it is raised
    again once ``fn`` is done. Exceptions of ``fn`` are raised in the caller. (Raw locks
    and ``_thread``: the threading module's waits are not safe against interrupts.)"""
    done = _thread.allocate_lock()
    done.acquire()
    box: list = []
    try:
        _thread.start_new_thread(_run_into, (fn, args, done, box))
    except RuntimeError:  # no new threads at interpreter shutdown: run it here
        return fn(*args)
    return _wait_done(done, box)


#: Writers not closed yet: closed at interpreter exit, so that an interrupt landing between a
#: writer's creation and the caller's ``try``/``with`` still leaves a complete file.
_OPEN_WRITERS: set = set()


@atexit.register
def _close_open_writers() -> None:
    for writer in list(_OPEN_WRITERS):
        try:
            writer._close_now()
        except BaseException:  # noqa: BLE001 - exiting anyway; the next writer still gets closed
            pass


def _normal_type(name: str) -> str:
    """``pkg/Type`` -> ``pkg/msg/Type`` (ROS 1 style names in foreign schemas)."""
    return name if name.count("/") == 2 else name.replace("/", "/msg/", 1)


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------

# MCAP record opcodes (https://mcap.dev/spec)
_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
_MESSAGE_INDEX, _CHUNK_INDEX, _ATTACHMENT, _ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
_STATISTICS, _METADATA, _METADATA_INDEX, _SUMMARY_OFFSET, _DATA_END = 0x0B, 0x0C, 0x0D, 0x0E, 0x0F
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4
#: Largest uncompressed chunk believed (bytes): a chunk holds at least one message.
MAX_CHUNK_BYTES = 1 << 32
_COMPRESSIONS = ("", "zstd", "lz4")
_TOPIC_RE = re.compile(r"^(/[A-Za-z0-9_~{}]+)+$")


class _Malformed(Exception):
    """A record does not parse (internal; always turned into a damage report)."""


class _Cursor:
    """Little-endian field reader over a bytes-like record body."""

    __slots__ = ("buf", "pos", "end")

    def __init__(self, buf, pos: int = 0, end: int | None = None):
        self.buf, self.pos = buf, pos
        self.end = len(buf) if end is None else end

    def take(self, n: int):
        if n < 0 or self.pos + n > self.end:
            raise _Malformed(f"field of {n} bytes runs past the record end")
        out = self.buf[self.pos:self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return struct.unpack_from("<H", self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack_from("<I", self.take(4))[0]

    def u64(self) -> int:
        return struct.unpack_from("<Q", self.take(8))[0]

    def string(self) -> str:
        raw = self.take(self.u32())
        try:
            return bytes(raw).decode("utf-8")
        except UnicodeDecodeError:
            raise _Malformed("string is not UTF-8") from None

    def str_map(self) -> dict:
        size = self.u32()
        sub = _Cursor(self.buf, self.pos, self.pos + size)
        if sub.end > self.end:
            raise _Malformed("map runs past the record end")
        out = {}
        while sub.pos < sub.end:
            key = sub.string()
            out[key] = sub.string()
        self.pos = sub.end
        return out

    def u16_u64_map(self) -> dict:
        size = self.u32()
        if size % 10:
            raise _Malformed(f"map of {size} bytes is not made of 10-byte entries")
        raw = self.take(size)
        return {k: v for k, v in struct.iter_unpack("<HQ", raw)}


@dataclass(frozen=True)
class SchemaRecord:
    """An MCAP schema record: ``id``, ``name`` (message type), ``encoding``, ``data`` (text)."""

    id: int
    name: str
    encoding: str
    data: bytes


@dataclass(frozen=True)
class ChannelRecord:
    """An MCAP channel record: ``id``, ``schema_id``, ``topic``, ``encoding``, ``metadata``."""

    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: dict


def _parse_schema(buf) -> SchemaRecord:
    c = _Cursor(buf)
    sid, name, encoding = c.u16(), c.string(), c.string()
    data = bytes(c.take(c.u32()))
    return SchemaRecord(sid, name, encoding, data)


def _parse_channel(buf) -> ChannelRecord:
    c = _Cursor(buf)
    cid, sid, topic, encoding = c.u16(), c.u16(), c.string(), c.string()
    meta = c.str_map()
    if c.pos != c.end:
        raise _Malformed("channel record has trailing bytes")
    return ChannelRecord(cid, sid, topic, encoding, meta)


class BagDamage(NamedTuple):
    """One damaged place of a bag.

    Attributes:
        offset: byte offset of the damaged record (or of the first byte that does
            not parse) in the file.
        length: bytes skipped there (0 when nothing had to be skipped).
        problem: what is wrong, one line.
        messages_lost: messages that could not be read because of it (None: unknown,
            e.g. a cut inside a chunk whose index never got written).
    """

    offset: int
    length: int
    problem: str
    messages_lost: int | None

    def describe(self, path) -> str:
        lost = ("" if self.messages_lost == 0 else
                f" ({'an unknown number of' if self.messages_lost is None else self.messages_lost}"
                f" message{'' if self.messages_lost == 1 else 's'} lost)")
        return f"{path}: offset {self.offset}: {self.problem}{lost}"


@dataclass
class _Chunk:
    offset: int  # of the record (opcode byte)
    length: int  # whole record, opcode and length field included
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data_offset: int
    data_length: int
    index_counts: dict = field(default_factory=dict)  # channel id -> messages (message indexes)
    index_times: list = field(default_factory=list)  # [min, max] log time from the message indexes
    after_resync: bool = False

    @property
    def expected(self) -> int | None:
        return sum(self.index_counts.values()) if self.index_counts else None

    @property
    def lower_ns(self) -> int:
        return min([self.start_ns] + self.index_times[:1])

    def may_hold(self, start_ns, end_ns) -> bool:
        """Whether a message with ``start_ns <= t < end_ns`` may be in the chunk (both the
        header and the message index must rule it out to skip the chunk)."""
        ranges = [(self.start_ns, self.end_ns)]
        if self.index_times:
            ranges.append((self.index_times[0], self.index_times[1]))
        for lo, hi in ranges:
            if lo > hi or ((start_ns is None or hi >= start_ns) and (end_ns is None or lo < end_ns)):
                return True
        return False


@dataclass
class BagCheck:
    """The outcome of :meth:`BagReader.verify`: what a full read of every chunk found.

    Attributes:
        path: the file.
        complete: the file ends with a valid summary and footer.
        chunks, chunks_damaged: chunks found, and how many of them are damaged.
        messages_recovered: topic -> messages that read intact.
        messages_lost: messages known lost; ``lost_unknown``: some losses cannot be counted.
        damage: every damaged place (:class:`BagDamage`).
        chunks_unverifiable: chunks stored without a CRC (their messages cannot be checked).
        data_crc: ``"ok"``, ``"mismatch"`` or ``"absent"`` (the writer stored none).
        summary: ``"ok"``, ``"damaged"`` or ``"absent"``.
    """

    path: Path
    complete: bool
    chunks: int
    chunks_damaged: int
    messages_recovered: dict
    messages_lost: int
    lost_unknown: bool
    damage: list
    data_crc: str
    summary: str
    chunks_unverifiable: int = 0

    @property
    def ok(self) -> bool:
        """No damage of any kind and a complete file."""
        return self.complete and not self.damage

    def lines(self) -> list[str]:
        """Human-readable report (integrity, topics, counts, what is recoverable)."""
        total = sum(self.messages_recovered.values())
        other = [d for d in self.damage if "cut short" not in d.problem]
        state = ("OK" if self.ok else "DAMAGED" if other else
                 "TRUNCATED (cut short or never closed: no summary/footer)")
        out = [f"bag: {self.path}", f"integrity: {state}",
               f"summary: {self.summary}; data-section CRC: {self.data_crc}; "
               f"chunks: {self.chunks} ({self.chunks_damaged} damaged"
               + (f", {self.chunks_unverifiable} without CRC: not verifiable" if self.chunks_unverifiable
                  else "") + ")"]
        for d in self.damage:
            out.append("  damage: " + d.describe(self.path).split(": ", 1)[1])
        lost = (f"{self.messages_lost} counted + an unknown number in unreadable parts"
                if self.lost_unknown else str(self.messages_lost))
        out.append(f"messages readable intact: {total}; lost: {lost}")
        for topic, n in sorted(self.messages_recovered.items()):
            out.append(f"  {topic}  {n} msgs")
        if not self.ok:
            out.append("recoverable: every message listed above (canopy-stereo bag repair FILE -o OUT)"
                       if total else "recoverable: nothing")
        return out


class BagReader:
    """Read a rosbag2 MCAP file (complete, cut short or damaged) without ever returning
    damaged data (see the module docstring).

    Args:
        path: the ``.mcap`` file.
        strict: raise :class:`BagError` at the first damage instead of skipping it.
        on_damage: ``f(BagDamage)`` called once for each damaged place as it is found.

    Attributes:
        path: the file.
        topics: topic -> :class:`TopicInfo` (``message_count``: messages stored; for a
            file without a valid summary, the messages that read intact).
        message_count, start_ns, end_ns: totals and log-time range (ns).
        truncated: the file ends early (no valid footer); messages up to the cut are
            still readable.
        problem: why the file is truncated or damaged ("" when neither is known).
        damage: every damaged place found so far (:class:`BagDamage`); reading the
            messages may find more (:meth:`verify` reads everything).
        messages_lost: messages known lost so far (``lost_unknown``: and maybe more).
        metadata_records: MCAP metadata records ``(name, dict)`` that were read intact
            (:meth:`metadata` gives them by name).
    """

    def __init__(self, path, *, strict: bool = False,
                 on_damage: Callable[[BagDamage], None] | None = None):
        self.path = Path(path)
        self.strict = bool(strict)
        self.on_damage = on_damage
        self.truncated = False
        self.problem = ""
        self.damage: list[BagDamage] = []
        self._damaged_at: set[int] = set()
        self.lost_unknown = False
        self.metadata_records: list[tuple[str, dict]] = []
        try:
            self._open()
        except BagError:
            self._close_fd()
            raise
        except MemoryError:
            self._close_fd()
            raise BagError(f"{self.path}: a size field asks for more memory than there is") from None
        except Exception as exc:  # noqa: BLE001 - last line of defence: one error type out
            self._close_fd()
            raise BagError(f"{self.path}: unreadable ({type(exc).__name__}: {_one_line(exc)})") from None

    # -- low level -----------------------------------------------------------------------------

    def _error(self, offset: int, problem: str) -> BagError:
        return BagError(f"{self.path}: offset {offset}: {problem}")

    def _read(self, offset: int, n: int) -> bytes:
        try:
            data = os.pread(self._fd, n, offset)
        except OSError as exc:
            raise self._error(offset, f"read failed ({exc.strerror or exc})") from None
        except (OverflowError, ValueError, MemoryError):
            raise self._error(offset, f"cannot read {n} bytes") from None
        return data

    def _close_fd(self) -> None:
        fd = getattr(self, "_fd", None)
        if fd is not None:
            try:
                os.close(fd)
            except OSError:
                pass
            self._fd = None

    def __del__(self):
        self._close_fd()

    def close(self) -> None:
        """Release the file (the reader cannot read afterwards)."""
        self._close_fd()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _report(self, damage: BagDamage) -> None:
        key = (damage.offset, damage.problem)
        if key in self._damaged_at:
            return
        self._damaged_at.add(key)
        self.damage.append(damage)
        if damage.messages_lost is None:
            self.lost_unknown = True
        if not self.problem:
            self.problem = damage.problem
        if self.on_damage is not None:
            self.on_damage(damage)
        if self.strict:
            raise BagError(damage.describe(self.path))

    @property
    def messages_lost(self) -> int:
        return sum(d.messages_lost or 0 for d in self.damage)

    # -- opening -------------------------------------------------------------------------------

    def _open(self) -> None:
        self._fd = None
        if self.path.is_dir():
            mcaps = sorted(p.name for p in self.path.glob("*.mcap"))
            raise BagError(f"{self.path} is a folder; pass one of its bag files"
                           + (f" ({', '.join(mcaps[:4])})" if mcaps else " (it holds no .mcap)"))
        if not self.path.is_file():
            raise BagError(f"bag not found: {self.path}")
        try:
            self._fd = os.open(self.path, os.O_RDONLY)
            self.size = os.fstat(self._fd).st_size
        except OSError as exc:
            raise BagError(f"cannot read bag {self.path}: {exc.strerror or exc}") from None
        if self.size == 0:
            raise BagError(f"{self.path}: offset 0: the file is empty (0 bytes)")
        if self._read(0, 8) != _MAGIC:
            raise BagError(f"{self.path}: offset 0: not an MCAP file (bad magic)")
        self._schemas: dict[int, SchemaRecord] = {}
        self._channels: dict[int, ChannelRecord] = {}
        self._chunks: list[_Chunk] = []
        self._chunk_problem: dict[int, str | None] = {}  # chunk offset -> problem (None: intact)
        self._loose: list[tuple[int, int]] = []  # (offset, length) of messages outside chunks
        self._loose_verified = True
        self._data_end: tuple[int, int] | None = None  # (offset, crc)
        self._profile = None
        self._summary_state = "absent"
        self._summary_verified = False
        footer = self._read_footer()
        # up to the footer, not to where it says the summary starts: that field is only
        # checked by the summary CRC (the scan stops at the data-end record anyway)
        self._scan(8, footer[3] if footer else self.size)
        summary = self._read_summary(footer) if footer else None
        if summary is not None and not self._believe(summary):
            summary = None
        self._summary = summary
        if summary is not None:
            self._schemas = dict(summary["schemas"])
            self._channels = dict(summary["channels"])
            stats = summary["statistics"]
            counts = dict(stats["counts"])
            start, end = stats["start"], stats["end"]
        else:
            counts, start, end = self._read_everything()
        if self._loose and self._data_end and self._data_end[1]:
            self._loose_verified = self._data_crc_ok()
            if not self._loose_verified:
                self._report(BagDamage(8, 0, "data-section CRC mismatch: the messages stored outside "
                                       "chunks cannot be verified and are skipped", len(self._loose)))
        self._build_topics(counts)
        if self.truncated and not self.problem:
            self.problem = "no summary section (the recorder did not close the file)"
        self.message_count = sum(t.message_count for t in self.topics.values())
        self.start_ns = int(start or 0) if self.message_count else 0
        self.end_ns = int(end or 0) if self.message_count else 0

    def _read_footer(self):
        """``(summary_start, summary_offset_start, crc, footer_offset)``, or None when the file
        does not end with a footer (cut short) or its footer is damaged."""
        if self.size < 8 + _FOOTER_SIZE + 8 or self._read(self.size - 8, 8) != _MAGIC:
            self.truncated = True
            self.problem = (f"the file ends at byte {self.size} without the closing footer "
                            "(cut short, or the recorder did not close it)")
            return None
        at = self.size - 8 - _FOOTER_SIZE
        raw = self._read(at, _FOOTER_SIZE)
        op, length, s_start, s_off, crc = struct.unpack("<BQQQI", raw)
        bad = None
        if op != _FOOTER or length != 20:
            bad = "footer record is damaged"
        elif s_start and not 8 < s_start <= at:
            bad = f"footer points at a summary at offset {s_start}, outside the file"
        elif s_off and not (s_start <= s_off <= at):
            bad = f"footer points at summary offsets at {s_off}, outside the summary"
        if bad:
            self._summary_state = "damaged"
            self._report(BagDamage(at, _FOOTER_SIZE, bad + "; the data is read without it", 0))
            return None
        return s_start, s_off, crc, at

    def _record_at(self, p: int, end: int):
        """``(opcode, body length)`` of the record at ``p``, or None when it cannot be one."""
        if p + 9 > end:
            return None
        op, length = struct.unpack("<BQ", self._read(p, 9))
        if op == 0 or (0x10 <= op < 0x80) or p + 9 + length > end:
            return None
        return op, length

    def _scan(self, start: int, end: int) -> None:
        """Walk the record framing of the data section ``[start, end)``: chunk headers,
        message indexes, loose records. Damage is reported; framing is recovered on the
        next intact chunk."""
        p = start
        last_chunk = None
        resynced = False
        while p < end:
            rec = self._record_at(p, end)
            if rec is not None and p == 8 and rec[0] != _HEADER:
                rec = None  # an MCAP file starts with its header record
            if rec is None:
                q = self._resync(p + 1, end)
                head = self._read(p, 9)
                op = head[0] if head else None
                cut = (end == self.size and op is not None and not (op == 0 or 0x10 <= op < 0x80)
                       and (p != 8 or op == _HEADER)
                       and (len(head) < 9 or p + 9 + struct.unpack_from("<Q", head, 1)[0] > end))
                if q is None:
                    if cut:  # no footer and a record that runs past the end: cut short here
                        self.truncated = True
                        self._report(BagDamage(p, end - p, f"the file is cut short: the record at "
                                               f"offset {p} ends past the end of the file "
                                               f"({self.size} bytes)", None if op == _CHUNK else 0))
                    else:
                        self._report(BagDamage(p, end - p, "unreadable record (opcode "
                                               f"{'none' if op is None else hex(op)}); no intact "
                                               "chunk follows", None))
                    return
                self._report(BagDamage(p, q - p, "unreadable record (opcode "
                                       f"{'none' if op is None else hex(op)}); skipped to the intact "
                                       f"chunk at {q}", None))
                p, resynced = q, True
                continue
            op, length = rec
            body_at = p + 9
            if op == _CHUNK:
                chunk = self._chunk_header(p, length)
                if chunk is None:  # header inconsistent: the length may lie too
                    q = self._resync(p + 1, end)
                    self._report(BagDamage(p, (q or end) - p, "damaged chunk header"
                                           + (f"; skipped to the intact chunk at {q}" if q else ""),
                                           None))
                    if q is None:
                        return
                    p, resynced = q, True
                    continue
                chunk.after_resync = resynced
                self._chunks.append(chunk)
                last_chunk = chunk
            elif op == _MESSAGE_INDEX and last_chunk is not None and length <= 1 << 28:
                try:
                    c = _Cursor(self._read(body_at, length))
                    cid = c.u16()
                    entries = c.take(c.u32())
                    if len(entries) % 16:
                        raise _Malformed("bad message index")
                    times = [t for t, _ in struct.iter_unpack("<QQ", entries)]
                    last_chunk.index_counts[cid] = last_chunk.index_counts.get(cid, 0) + len(times)
                    if times:
                        lo, hi = min(times), max(times)
                        it = last_chunk.index_times
                        last_chunk.index_times = [min(it[0], lo), max(it[1], hi)] if it else [lo, hi]
                except _Malformed:
                    pass  # only the loss count of that chunk becomes unknown
            elif op == _HEADER and p == 8:
                try:
                    c = _Cursor(self._read(body_at, min(length, 1 << 20)))
                    self._profile = c.string()
                except _Malformed:
                    self._report(BagDamage(p, 9 + length, "damaged MCAP header record", 0))
            elif op in (_SCHEMA, _CHANNEL) and length <= 1 << 26 and not resynced:
                try:
                    body = self._read(body_at, length)
                    if op == _SCHEMA:
                        s = _parse_schema(body)
                        self._schemas.setdefault(s.id, s)
                    else:
                        ch = _parse_channel(body)
                        self._channels.setdefault(ch.id, ch)
                except _Malformed as exc:
                    kind = "schema" if op == _SCHEMA else "channel"
                    self._report(BagDamage(p, 9 + length, f"damaged {kind} record ({exc})", 0))
            elif op == _MESSAGE:
                if resynced:  # after a framing break only CRC-checked chunks are believed
                    self._report(BagDamage(p, 9 + length, "message record after damaged framing", 1))
                else:
                    self._loose.append((p, length))
            elif op == _METADATA and length <= 1 << 26:
                try:
                    c = _Cursor(self._read(body_at, length))
                    self.metadata_records.append((c.string(), c.str_map()))
                except _Malformed as exc:
                    self._report(BagDamage(p, 9 + length, f"damaged metadata record ({exc})", 0))
            elif op == _DATA_END:
                crc = struct.unpack("<I", self._read(body_at, 4))[0] if length >= 4 else 0
                self._data_end = (p, crc)
                return
            elif op == _FOOTER:
                return
            p = body_at + length
        if end == self.size and not self.truncated:
            self.truncated = True

    def _chunk_header(self, p: int, length: int) -> _Chunk | None:
        """The chunk record at ``p`` if its header is self-consistent, else None."""
        head = self._read(p + 9, min(length, 8 + 8 + 8 + 4 + 4 + 16 + 8))
        if len(head) < 32:
            return None
        start, end, usize, crc, clen = struct.unpack_from("<QQQII", head)
        if clen > 16 or len(head) < 32 + clen + 8:
            return None
        try:
            comp = head[32:32 + clen].decode("ascii")
        except UnicodeDecodeError:
            return None
        data_len = struct.unpack_from("<Q", head, 32 + clen)[0]
        header_len = 32 + clen + 8
        if (comp not in _COMPRESSIONS or header_len + data_len != length or usize > MAX_CHUNK_BYTES
                or (comp == "" and usize != data_len)):
            return None
        return _Chunk(p, 9 + length, start, end, usize, crc, comp, p + 9 + header_len, data_len)

    def _resync(self, p: int, end: int) -> int | None:
        """Offset of the next chunk at or after ``p`` that reads intact, or None."""
        block = 1 << 20
        pos = p
        while pos < end:
            buf = self._read(pos, min(block + 64, end - pos))
            i = buf.find(b"\x06")
            while i != -1 and i < block:
                q = pos + i
                rec = self._record_at(q, end)
                if rec is not None and rec[0] == _CHUNK:
                    chunk = self._chunk_header(q, rec[1])
                    if chunk is not None and self._decompress(chunk)[0] is not None:
                        return q
                i = buf.find(b"\x06", i + 1)
            pos += block
        return None

    def _read_summary(self, footer):
        """The summary section parsed, after its CRC; None (reported) when damaged or absent."""
        s_start, s_off, crc, at = footer
        if not s_start:
            self._summary_state = "absent"
            return None
        raw = self._read(s_start, at - s_start)
        tail = struct.pack("<BQQQ", _FOOTER, 20, s_start, s_off)
        if not crc:  # nothing vouches for it: the topics and counts are read from the data
            self._summary_state = "no CRC"
            return None
        if zlib.crc32(tail, zlib.crc32(raw)) != crc:
            return self._summary_damaged(s_start, at, "summary section CRC mismatch")
        self._summary_verified = True
        out = {"schemas": {}, "channels": {}, "statistics": None, "chunk_indexes": []}
        c = _Cursor(raw)
        try:
            while c.pos < c.end:
                op = c.take(1)[0]
                body = _Cursor(c.take(c.u64()))
                if op == _SCHEMA:
                    s = _parse_schema(body.buf)
                    out["schemas"][s.id] = s
                elif op == _CHANNEL:
                    ch = _parse_channel(body.buf)
                    out["channels"][ch.id] = ch
                elif op == _STATISTICS:
                    st = {"messages": body.u64(), "schemas": body.u16(), "channels": body.u32(),
                          "attachments": body.u32(), "metadata": body.u32(), "chunks": body.u32(),
                          "start": body.u64(), "end": body.u64()}
                    st["counts"] = body.u16_u64_map()
                    out["statistics"] = st
                elif op == _CHUNK_INDEX:
                    ci = {"start": body.u64(), "end": body.u64(), "offset": body.u64(),
                          "length": body.u64()}
                    body.u16_u64_map()
                    body.u64()
                    ci["compression"] = body.string()
                    ci["compressed"], ci["uncompressed"] = body.u64(), body.u64()
                    out["chunk_indexes"].append(ci)
        except _Malformed as exc:
            return self._summary_damaged(s_start, at, f"summary section does not parse ({exc})")
        self._summary_state = "ok"
        return out

    def _summary_damaged(self, s_start: int, at: int, problem: str):
        self._summary_state = "damaged"
        self._report(BagDamage(s_start, at - s_start, problem + "; topics and counts are taken "
                               "from the data instead", 0))
        return None

    def _believe(self, summary) -> bool:
        """Sanity checks of a summary (whose CRC matched) against itself and the data.

        A summary that contradicts itself (counts that do not add up, invalid topic names,
        missing schemas, offsets outside the file) is not believed. Where it disagrees with
        the data records (which no CRC protects), the data records are the damaged ones:
        chunk headers are corrected from the chunk indexes, and chunks the scan could not
        reach are added from them (every chunk is CRC-checked before use)."""
        own, cross = [], []
        st = summary["statistics"]
        schemas, channels = summary["schemas"], summary["channels"]
        if st is None:
            own.append("no statistics record")
        else:
            if st["messages"] != sum(st["counts"].values()):
                own.append(f"message count {st['messages']} is not the sum of the "
                           f"per-channel counts ({sum(st['counts'].values())})")
            if set(st["counts"]) - set(channels):
                own.append(f"counts for unknown channels {sorted(set(st['counts']) - set(channels))}")
            if st["messages"] and st["start"] > st["end"]:
                own.append("message start time after end time")
            if st["channels"] != len(channels) or st["schemas"] != len(schemas):
                own.append("schema/channel counts disagree with the records")
            if st["chunks"] != len(summary["chunk_indexes"]) and summary["chunk_indexes"]:
                own.append(f"{st['chunks']} chunks announced, {len(summary['chunk_indexes'])} indexed")
        for ch in channels.values():
            if not _TOPIC_RE.match(ch.topic):
                own.append(f"channel {ch.id} has an invalid topic name {ch.topic!r}")
            elif ch.schema_id not in schemas:
                own.append(f"channel {ch.topic} refers to a missing schema {ch.schema_id}")
        for ci in summary["chunk_indexes"]:
            if not (8 < ci["offset"] and ci["offset"] + ci["length"] <= self.size) or \
                    ci["compression"] not in _COMPRESSIONS or ci["uncompressed"] > MAX_CHUNK_BYTES:
                own.append(f"chunk index points at offset {ci['offset']}, outside the file")
                break
        if own:
            return self._reject_summary(own)
        if st is not None:
            if st["chunks"] != len(self._chunks):
                cross.append(f"{st['chunks']} chunks announced, {len(self._chunks)} found")
            by_channel: dict = {}
            complete_index = all(c.index_counts for c in self._chunks)
            for c in self._chunks:
                for cid, n in c.index_counts.items():
                    by_channel[cid] = by_channel.get(cid, 0) + n
            if complete_index and {k: v for k, v in st["counts"].items() if v} != by_channel:
                cross.append("per-channel message counts disagree with the message indexes")
        for cid, ch in self._channels.items():  # channels seen outside chunks
            if cid in channels and channels[cid] != ch:
                cross.append(f"channel {cid} differs between the data and the summary")
        found = {c.offset: c for c in self._chunks}
        fixes = []
        for ci in summary["chunk_indexes"]:
            c = found.get(ci["offset"])
            fields = (ci["length"], ci["compression"], ci["uncompressed"], ci["start"], ci["end"])
            if c is None or (c.length, c.compression, c.uncompressed_size, c.start_ns, c.end_ns) != fields:
                cross.append(f"the chunk at offset {ci['offset']} "
                             + ("was not reached by the scan" if c is None else "disagrees with its index"))
                fixes.append(ci)
        if not cross:
            return True
        for ci in fixes:  # the CRC-checked index is right; the record header is not
            c = found.get(ci["offset"])
            clen = len(ci["compression"])
            data_offset = ci["offset"] + 9 + 32 + clen + 8
            fixed = _Chunk(ci["offset"], ci["length"], ci["start"], ci["end"], ci["uncompressed"],
                           c.crc if c is not None else self._chunk_crc_at(ci["offset"]),
                           ci["compression"], data_offset, ci["compressed"])
            if c is not None:
                fixed.index_counts, fixed.index_times = c.index_counts, c.index_times
                self._chunks[self._chunks.index(c)] = fixed
            else:
                self._chunks.append(fixed)
        self._chunks.sort(key=lambda c: c.offset)
        self._report(BagDamage(self._footer_summary_start(), 0, "data records disagree with the "
                               "summary (" + "; ".join(cross[:2]) + "); the summary, whose CRC "
                               "matches, is used", 0))
        return True

    def _chunk_crc_at(self, offset: int) -> int:
        raw = self._read(offset + 9 + 24, 4)
        return struct.unpack("<I", raw)[0] if len(raw) == 4 else 0

    def _reject_summary(self, problems) -> bool:
        self._summary_state = "damaged"
        self._report(BagDamage(self._footer_summary_start(), 0, "summary not believed: "
                               + "; ".join(problems[:3]) + "; topics and counts are taken from "
                               "the data instead", 0))
        return False

    def _footer_summary_start(self) -> int:
        at = self.size - 8 - _FOOTER_SIZE
        return struct.unpack("<Q", self._read(at + 9, 8))[0]

    def _read_everything(self):
        """Without a believable summary: read every chunk once to learn the topics and count
        the intact messages. Returns ``(counts by channel, start_ns, end_ns)``."""
        counts: dict[int, int] = {}
        start = end = None
        for chunk in self._chunks:
            for cid, log_time, *_ in self._chunk_messages(chunk, learn=True):
                counts[cid] = counts.get(cid, 0) + 1
                start = log_time if start is None else min(start, log_time)
                end = log_time if end is None else max(end, log_time)
        for cid, log_time, *_ in self._loose_messages(learn=True):
            counts[cid] = counts.get(cid, 0) + 1
            start = log_time if start is None else min(start, log_time)
            end = log_time if end is None else max(end, log_time)
        return counts, start, end

    def _build_topics(self, counts: dict) -> None:
        self.topics: dict[str, TopicInfo] = {}
        self._channel_types: dict[int, str] = {}
        profile_ok = self._profile in (None, "ros2")
        for cid, ch in sorted(self._channels.items()):
            schema = self._schemas.get(ch.schema_id)
            if schema is None:
                raise BagError(f"{self.path}: channel {ch.topic} has no schema")
            if ch.encoding != "cdr":
                raise BagError(f"{self.path}: topic {ch.topic} is {ch.encoding}, not cdr")
            tname = _normal_type(schema.name)
            self._channel_types[cid] = tname
            info = self.topics.setdefault(ch.topic, TopicInfo(
                ch.topic, tname, 0, schema.data.decode("utf-8", "replace"),
                ch.metadata.get("offered_qos_profiles", "")))
            info.message_count += int(counts.get(cid, 0))
        if not profile_ok and not self._channels:
            raise BagError(f"{self.path}: MCAP profile is {self._profile!r}, not ros2")

    # -- chunks --------------------------------------------------------------------------------

    def _decompress(self, chunk: _Chunk):
        """``(records bytes, None)`` when the chunk is intact, else ``(None, problem)``."""
        raw = self._read(chunk.data_offset, chunk.data_length)
        if len(raw) != chunk.data_length:
            return None, "chunk ends past the end of the file"
        if chunk.compression == "lz4" and chunk.uncompressed_size > 256 * len(raw) + (1 << 16):
            return None, f"uncompressed size {chunk.uncompressed_size} is impossible for lz4 data"
        try:
            if chunk.compression == "zstd":
                import zstandard

                declared = zstandard.frame_content_size(raw)
                if declared >= 0 and declared != chunk.uncompressed_size:
                    return None, (f"zstd frame holds {declared} bytes, the chunk header says "
                                  f"{chunk.uncompressed_size}")
                data = zstandard.ZstdDecompressor().decompress(
                    raw, max_output_size=max(1, chunk.uncompressed_size))
            elif chunk.compression == "lz4":
                import lz4.frame

                data = lz4.frame.LZ4FrameDecompressor().decompress(
                    raw, max_length=chunk.uncompressed_size + 1)
            else:
                data = raw
        except MemoryError:
            return None, f"{chunk.compression} data asks for more memory than there is"
        except Exception as exc:  # noqa: BLE001 - zstandard/lz4 raise their own types on bad data
            return None, f"{chunk.compression} data does not decompress ({_one_line(exc)})"
        if len(data) != chunk.uncompressed_size:
            return None, (f"chunk holds {len(data)} bytes uncompressed, its header says "
                          f"{chunk.uncompressed_size}")
        if chunk.crc and zlib.crc32(data) != chunk.crc:
            return None, "chunk CRC mismatch"
        return data, None

    def _chunk_messages(self, chunk: _Chunk, learn: bool = False) -> list:
        """The messages of an intact chunk as ``(channel id, log, publish, sequence, data)``
        tuples in chunk order; [] (and a damage report) when the chunk is damaged."""
        if self._chunk_problem.get(chunk.offset):
            return []
        data, problem = self._decompress(chunk)
        out = []
        if problem is None:
            try:
                out = self._parse_chunk(chunk, data, learn)
            except _Malformed as exc:
                problem = f"chunk records do not parse ({exc})"
        self._chunk_problem[chunk.offset] = problem
        if problem is not None:
            self._report(BagDamage(chunk.offset, chunk.length, problem, chunk.expected))
            return []
        return out

    def _parse_chunk(self, chunk: _Chunk, data, learn: bool) -> list:
        view = memoryview(data)
        c = _Cursor(view)
        out = []
        unknown = 0
        while c.pos < c.end:
            op = c.take(1)[0]
            body = c.take(c.u64())
            if op == _MESSAGE:
                if len(body) < 22:
                    raise _Malformed("message record shorter than its fields")
                cid, seq, log_time, pub_time = struct.unpack_from("<HIQQ", body)
                if cid not in self._channels:
                    unknown += 1
                    continue
                out.append((cid, log_time, pub_time, seq, body[22:]))
            elif op == _SCHEMA:
                s = _parse_schema(body)
                if learn:
                    self._schemas.setdefault(s.id, s)
            elif op == _CHANNEL:
                ch = _parse_channel(body)
                if learn:
                    self._channels.setdefault(ch.id, ch)
                elif ch.id in self._channels and self._channels[ch.id] != ch:
                    raise _Malformed(f"channel {ch.id} differs from the summary's")
        if unknown:
            self._report(BagDamage(chunk.offset, 0, f"{unknown} messages of the chunk refer to a "
                                   "channel whose definition was lost", unknown))
        if out and chunk.crc:
            times = [m[1] for m in out]
            if min(times) < chunk.start_ns or max(times) > chunk.end_ns:
                self._report(BagDamage(chunk.offset, 0, "chunk header time range does not cover its "
                                       "messages (the messages themselves are intact)", 0))
        return out

    def _loose_messages(self, learn: bool = False) -> list:
        if not self._loose_verified:
            return []
        out = []
        for p, length in self._loose:
            body = self._read(p + 9, length)
            if len(body) < 22:
                self._report(BagDamage(p, 9 + length, "message record shorter than its fields", 1))
                continue
            cid, seq, log_time, pub_time = struct.unpack_from("<HIQQ", body)
            if cid not in self._channels:
                self._report(BagDamage(p, 9 + length, f"message for unknown channel {cid}", 1))
                continue
            out.append((cid, log_time, pub_time, seq, memoryview(body)[22:]))
        return out

    def _data_crc_ok(self) -> bool:
        at, crc = self._data_end
        value, pos = 0, 0
        while pos < at:
            block = self._read(pos, min(1 << 24, at - pos))
            if not block:
                return False
            value = zlib.crc32(block, value)
            pos += len(block)
        return value == crc

    # -- public reading --------------------------------------------------------------------------

    def messages(self, topics=None, start_ns: int | None = None, *, end_ns: int | None = None,
                 log_time_order: bool = True) -> Iterator[BagMessage]:
        """Serialized messages, each from a chunk whose CRC was checked.

        Damaged chunks are skipped (recorded in :attr:`damage`; :class:`BagError` with
        ``strict``).

        Args:
            topics: topic names to keep (None: all).
            start_ns, end_ns: keep ``start_ns <= log_time < end_ns`` (absolute ns).
            log_time_order: merge the chunks into log-time order (else file order).
        """
        try:
            yield from self._messages(topics, start_ns, end_ns, log_time_order)
        except (BagError, GeneratorExit):
            raise
        except MemoryError:
            raise BagError(f"{self.path}: a chunk needs more memory than there is") from None
        except Exception as exc:  # noqa: BLE001 - last line of defence: one error type out
            raise BagError(f"{self.path}: unreadable ({type(exc).__name__}: {_one_line(exc)})") from None

    def _messages(self, topics, start_ns, end_ns, log_time_order):
        if self._fd is None:
            raise BagError(f"{self.path}: the reader is closed")
        wanted = None if topics is None else set([topics] if isinstance(topics, str) else topics)
        cids = {cid for cid, ch in self._channels.items() if wanted is None or ch.topic in wanted}
        types = self._channel_types
        topic_of = {cid: ch.topic for cid, ch in self._channels.items()}

        def keep(cid, t):
            return cid in cids and (start_ns is None or t >= start_ns) and (end_ns is None or t < end_ns)

        def make(m):
            cid, log_time, pub_time, _, data = m
            return BagMessage(topic_of[cid], types[cid], log_time, pub_time, bytes(data))

        # (message indexes are not CRC-protected: a chunk is skipped only when both its
        # header and its index rule it out)
        chunks = [c for c in self._chunks if c.may_hold(start_ns, end_ns)]
        loose = [m for m in self._loose_messages() if keep(m[0], m[1])]
        if not log_time_order:
            for m in loose:
                yield make(m)
            for chunk in chunks:
                for m in self._chunk_messages(chunk):
                    if keep(m[0], m[1]):
                        yield make(m)
            return
        order = sorted(chunks, key=lambda c: (c.lower_ns, c.offset))
        heap = [(m[1], -1, k, m) for k, m in enumerate(loose)]
        heapq.heapify(heap)
        i = 0
        while i < len(order) or heap:
            while i < len(order) and (not heap or order[i].lower_ns <= heap[0][0]):
                for k, m in enumerate(self._chunk_messages(order[i])):
                    if keep(m[0], m[1]):
                        heapq.heappush(heap, (m[1], i, k, m))
                i += 1
            if heap:
                yield make(heapq.heappop(heap)[3])

    def metadata(self) -> dict[str, dict[str, str]]:
        """The file's MCAP metadata records that read intact, ``{name: {key: value}}`` (the
        ``rosbag2`` record included when the file has one; a later record of the same name
        wins). A truncated or damaged file yields the records found intact."""
        return {name: dict(data) for name, data in self.metadata_records}

    def read(self, topics=None, start_ns=None, *, end_ns=None):
        """``(BagMessage, decoded message)`` pairs in log-time order (:class:`BagError` for a
        message that is not valid CDR)."""
        for m in self.messages(topics, start_ns, end_ns=end_ns):
            yield m, m.decode()

    def verify(self) -> BagCheck:
        """Read every chunk (CRC, size, records) and the data-section CRC; return the report."""
        try:
            return self._verify()
        except BagError:
            raise
        except MemoryError:
            raise BagError(f"{self.path}: a chunk needs more memory than there is") from None
        except Exception as exc:  # noqa: BLE001 - last line of defence: one error type out
            raise BagError(f"{self.path}: unreadable ({type(exc).__name__}: {_one_line(exc)})") from None

    def _verify(self) -> BagCheck:
        recovered: dict[str, int] = {}
        for chunk in self._chunks:
            for m in self._chunk_messages(chunk):
                topic = self._channels[m[0]].topic
                recovered[topic] = recovered.get(topic, 0) + 1
        for m in self._loose_messages():
            topic = self._channels[m[0]].topic
            recovered[topic] = recovered.get(topic, 0) + 1
        data_crc = "absent"
        if self._data_end and self._data_end[1]:
            data_crc = "ok" if self._data_crc_ok() else "mismatch"
            if data_crc == "mismatch" and not self._loose:
                self._report(BagDamage(self._data_end[0], 0, "data-section CRC mismatch (outside "
                                       "the chunks: indexes or metadata; every message read was "
                                       "checked by its chunk CRC)", 0))
        lost, unknown = self.messages_lost, self.lost_unknown
        if self._summary is not None:  # the believed summary knows how many were stored
            lost = max(0, sum(self._summary["statistics"]["counts"].values()) - sum(recovered.values()))
            unknown = False
        for topic in self.topics:
            recovered.setdefault(topic, 0)
        damaged = sum(1 for c in self._chunks if self._chunk_problem.get(c.offset))
        return BagCheck(self.path, not self.truncated and self._summary_state != "damaged", len(self._chunks),
                        damaged, recovered, lost, unknown, list(self.damage), data_crc,
                        self._summary_state, sum(1 for c in self._chunks if not c.crc))

    def summary_text(self) -> str:
        """A short human-readable description (like ``ros2 bag info``)."""
        dur = (self.end_ns - self.start_ns) / 1e9 if self.message_count else 0.0
        lines = [f"bag: {self.path}", f"messages: {self.message_count}, duration: {dur:.3f} s"]
        if self.truncated:
            lines.append(f"TRUNCATED: {self.problem}")
        for d in self.damage:
            lines.append("DAMAGED: " + d.describe(self.path).split(": ", 1)[1])
        for t in sorted(self.topics.values(), key=lambda t: t.name):
            lines.append(f"  {t.name}  {t.type_name}  {t.message_count} msgs")
        return "\n".join(lines)


def repair_bag(src, dst, *, compression: str | None = None, overwrite: bool = False) -> BagCheck:
    """Write every intact message of ``src`` (a damaged or unclosed bag) to a new, complete
    bag ``dst``; returns the check of ``src``. Metadata records that read intact (other than
    rosbag2's own, which is rewritten) are copied.

    Args:
        compression: chunk compression of ``dst`` (default: that of ``src``'s chunks, else zstd).
        overwrite: replace an existing ``dst``.
    """
    src, dst = Path(src), Path(dst)
    if dst.resolve() == src.resolve():
        raise BagError(f"{dst}: repair needs another output file than its input")
    reader = BagReader(src)
    if compression is None:
        comps = {c.compression for c in reader._chunks}
        compression = comps.pop() if len(comps) == 1 else "zstd"
        compression = compression or "none"
    writer = BagWriter(dst, compression=compression, overwrite=overwrite, flush_period_s=0)
    try:
        for topic, info in reader.topics.items():
            writer.add_topic(topic, info.type_name, qos_yaml=info.qos_yaml, definition=info.definition)
        for name, data in reader.metadata_records:
            if name != "rosbag2":
                writer.add_metadata(name, data)
        for m in reader.messages(log_time_order=True):
            writer.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns,
                         msg_type=m.type_name)
    finally:
        writer.close()
    return reader.verify()


_SIZE_UNITS = {"": 1, "B": 1, "K": 1 << 10, "KB": 1 << 10, "KIB": 1 << 10, "M": 1 << 20, "MB": 1 << 20,
               "MIB": 1 << 20, "G": 1 << 30, "GB": 1 << 30, "GIB": 1 << 30}


def parse_size(text) -> int:
    """Bytes from ``"1048576"``, ``"500M"``, ``"2G"``, ``"64KiB"`` (binary units)."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([A-Za-z]*)\s*", str(text))
    if not m or m.group(2).upper() not in _SIZE_UNITS:
        raise CanopyStereoError(f"size {text!r} is not a number of bytes (e.g. 500M, 2G)")
    return int(float(m.group(1)) * _SIZE_UNITS[m.group(2).upper()])


def add_split_arguments(parser) -> None:
    """``--split-size`` and ``--split-duration`` (rosbag2-style bag splitting) for a recorder."""
    parser.add_argument("--split-size", default="0", metavar="BYTES",
                        help="start a new file <name>_N.mcap when the current one reaches this "
                             "size (e.g. 500M, 2G; default 0 = never)")
    parser.add_argument("--split-duration", type=float, default=0.0, metavar="S",
                        help="start a new file <name>_N.mcap every S seconds of recording "
                             "(default 0 = never)")


def split_options(args) -> dict:
    """``{"split_size": ..., "split_duration_s": ...}`` from :func:`add_split_arguments` options
    (:class:`~canopy_stereo.errors.CanopyStereoError` for bad values)."""
    size = parse_size(args.split_size)
    duration = float(args.split_duration)
    if not duration >= 0 or duration == float("inf"):
        raise CanopyStereoError(f"--split-duration must be a finite number >= 0, got {args.split_duration}")
    return {"split_size": size, "split_duration_s": duration}
