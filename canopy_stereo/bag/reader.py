"""rosbag2 MCAP bags read with checks at every step (:class:`BagReader`).

:class:`BagReader` never returns damaged data. It walks the record framing of
the file itself, checks every chunk's CRC (and size, compression, record
layout) before it yields a message of that chunk, and believes the summary
(topics, counts, times, chunk indexes) only when its CRC matches and it agrees
with the data actually found. A damaged chunk is reported
(:attr:`BagReader.damage`: byte offset, problem, messages lost) and skipped;
the chunks around it are still read (the reader resynchronises on the next
intact chunk). A file cut short (a recorder that never closed it) is read up to
the cut and says so (:attr:`BagReader.truncated`). Every failure is a
:class:`~canopy_stereo.bag.errors.BagError` with one line naming the file, the byte
offset and the problem. The format written: :mod:`canopy_stereo.bag.writer`.
"""
from __future__ import annotations

import heapq
import os
import struct
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

from canopy_stereo.bag.check import BagCheck, BagDamage
from canopy_stereo.bag.errors import BagError, _one_line
from canopy_stereo.bag.mcap_records import (
    _CHANNEL,
    _CHUNK,
    _CHUNK_INDEX,
    _COMPRESSIONS,
    _DATA_END,
    _FOOTER,
    _FOOTER_SIZE,
    _HEADER,
    _MAGIC,
    _MESSAGE,
    _MESSAGE_INDEX,
    _METADATA,
    _SCHEMA,
    _STATISTICS,
    _TOPIC_RE,
    MAX_CHUNK_BYTES,
    ChannelRecord,
    SchemaRecord,
    _Chunk,
    _Cursor,
    _Malformed,
    _parse_channel,
    _parse_schema,
)
from canopy_stereo.bag.messages import BagMessage, TopicInfo, _normal_type


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
        self._damaged_at: set[tuple[int, str]] = set()
        self._fd: int | None = None
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
        if self._fd is None:
            raise BagError(f"{self.path}: the reader is closed")
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
            self._fd = fd = os.open(self.path, os.O_RDONLY)
            self.size = os.fstat(fd).st_size
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
        self._profile: str | None = None
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
            for chunk in self._chunks:
                for cid, n in chunk.index_counts.items():
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
        assert self._data_end is not None  # called only when the data-end record was read
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
