"""rosbag2-compatible MCAP bags, written with checks at every step (:class:`BagWriter`).

Files follow what rosbag2's MCAP storage plugin writes, so ``ros2 bag play``,
``ros2 bag info``, ``rosbags`` and Foxglove read them:

* header profile ``ros2``; one schema per message type with encoding
  ``ros2msg`` and the full definition text (:mod:`~canopy_stereo.bag.msgdefs`);
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
  :mod:`canopy_stereo.bag.metadata`); the pairs of the ``canopy_stereo`` record are
  also rosbag2's ``custom_data`` (what ``ros2 bag record --custom-data`` writes), for
  tools that know only rosbag2.

:class:`BagWriter` ends the chunk in progress and fsyncs the file every
``flush_period_s`` (1 s), so a recorder killed with SIGKILL (or a power cut)
loses at most the messages of the last second: the rest reads as a truncated
bag, and ``canopy-stereo bag repair`` turns it into a complete one. With
``split_size``/``split_duration_s`` it rotates to ``<name>_0.mcap``,
``<name>_1.mcap``, ... like rosbag2's bag splitting. Every file of a split recording opens
alone: each repeats, at its start, the messages of the latched topics (recorded with
``transient_local`` durability, e.g. ``/tf_static``, ``stereo_geometry``) written so far
(at most :data:`LATCHED_KEPT` per topic, the newest), with the log time of the file's first
message and their own publish time, as a late subscriber to a latched topic receives them.
"""
from __future__ import annotations

import _thread
import atexit
import os
import queue
import threading
from pathlib import Path
from typing import Any

import yaml
from mcap.writer import CompressionType, Writer

from canopy_stereo.bag.errors import BagError
from canopy_stereo.bag.interrupts import _run_into, _run_to_end, _wait_done
from canopy_stereo.bag.messages import TopicInfo, _normal_type, _stamp_of, qos_profiles_yaml
from canopy_stereo.bag.metadata import METADATA_RECORD
from canopy_stereo.bag.msgdefs import message_class, message_definition, serialize, type_name
from canopy_stereo.bag.split import split_file_path

#: Messages of one latched (transient local) topic repeated at the start of every split file.
LATCHED_KEPT = 100


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
        self._latched: dict[str, list[tuple[bytes, int]]] = {}  # topic -> [(data, publish time)]
        self.custom_data: dict[str, str] = {}  # rosbag2's custom_data: the canopy_stereo record
        self.topics: dict[str, TopicInfo] = {}
        self._lock = threading.RLock()
        self._start_ns: int | None = None
        self._end_ns = 0
        self.message_count = 0
        self.closed = False
        # the open file and its mcap Writer, from _open_next on (None only while it opens)
        self._file: Any = None
        self._writer: Any = None
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

    def _rotate(self, log_time_ns: int) -> None:
        self._finish_file()
        self._open_next()
        for topic, kept in self._latched.items():  # the new file opens alone (see module docstring)
            for data, publish_ns in kept:
                self._add_message(topic, data, log_time_ns, publish_ns, repeat=True)

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
            msg_type = msg_type or type_name(msg)
            data = serialize(msg)
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
                self._rotate(log_time_ns)
            if self.splitting and "transient_local" in self.topics[topic].qos_yaml:
                kept = self._latched.setdefault(topic, [])
                kept.append((data, publish_time_ns))
                del kept[:-LATCHED_KEPT]
            self._add_message(topic, data, log_time_ns, publish_time_ns)

    def _add_message(self, topic, data, log_time_ns, publish_time_ns, *, repeat: bool = False) -> None:
        with self._lock:
            info = self.topics[topic]
            self._io(self._writer.add_message, channel_id=self._channels[topic], log_time=log_time_ns,
                     data=data, publish_time=publish_time_ns, sequence=info.message_count)
            self._pending += len(data) + 31
            if self._pending > self._chunk_size:
                self._pending = 0  # the writer ended the chunk
            self._dirty = True
            if not repeat:  # a latched message repeated in a split file is not a new message
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
