"""MCAP record framing (https://mcap.dev/spec), parsed field by field for the reader.

Opcodes, a little-endian field cursor over a record body, the schema and channel
records, and a chunk's header as the reader keeps it. Anything that does not parse
raises :class:`_Malformed` (internal; the reader turns it into a damage report).
"""
from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field

_MAGIC = b"\x89MCAP0\r\n"

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

