"""``sensor_msgs/msg/CompressedImage`` as CDR bytes, written and read without ROS.

Bag readers on machines without ROS (batch workers) and bag writers that are not
nodes (the simulator) use these; the ROS nodes use rclpy's messages
(:mod:`canopy_stereo.ros.compressed`). The pixels are encoded and decoded by
:mod:`canopy_stereo.io.image_codec`.

CDR layout after the 4-byte encapsulation header (``00 01`` little-endian, ``00 00``
big-endian; alignment counted from the end of that header): ``int32 sec, uint32 nanosec,
string frame_id, string format, sequence<uint8> data`` (strings and sequences: ``uint32``
length, then the bytes; strings include their terminating NUL).

image_transport's convention for topics: the compressed stream of ``<ns>/image_raw`` is
``<ns>/image_raw/compressed`` (:func:`compressed_topic`).
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY, decode_compressed, encode_compressed

#: The message type's name in bags.
COMPRESSED_IMAGE_TYPE = "sensor_msgs/msg/CompressedImage"

#: The raw image type's name in bags.
IMAGE_TYPE = "sensor_msgs/msg/Image"

#: Suffix of image_transport's compressed topics.
COMPRESSED_SUFFIX = "/compressed"

_NS = 1_000_000_000


def compressed_topic(topic: str) -> str:
    """image_transport's compressed topic of a raw image topic (``.../image_raw`` ->
    ``.../image_raw/compressed``)."""
    return topic.rstrip("/") + COMPRESSED_SUFFIX


@dataclass(frozen=True)
class CompressedFrame:
    """A ``sensor_msgs/msg/CompressedImage``: header stamp (ns), frame, ``format`` and bytes."""

    stamp_ns: int
    frame_id: str
    format: str
    data: memoryview

    def to_bgr(self, expected_size=None) -> np.ndarray:
        """The decoded frame, uint8 BGR (H, W, 3) (:func:`~canopy_stereo.io.image_codec.decode_compressed`)."""
        return decode_compressed(self.data, self.format, expected_size=expected_size)


def _string(s: str, pos: int) -> bytes:
    data = s.encode("utf-8") + b"\0"
    return b"\0" * ((-pos) % 4) + struct.pack("<I", len(data)) + data


def compressed_image_cdr(*, stamp_ns: int, frame_id: str, fmt: str, data) -> bytes:
    """CDR bytes (little-endian) of a ``sensor_msgs/msg/CompressedImage``, what rclpy would
    serialize: ``stamp_ns`` (ns, >= 0), ``frame_id``, ``format`` and the compressed ``data``."""
    stamp_ns = int(stamp_ns)
    if stamp_ns < 0:
        raise ImageError(f"stamp must be >= 0 ns, got {stamp_ns}")
    out = bytearray(struct.pack("<iI", stamp_ns // _NS, stamp_ns % _NS))
    out += _string(frame_id, len(out))
    out += _string(fmt, len(out))
    payload = memoryview(data).cast("B")
    out += b"\0" * ((-len(out)) % 4) + struct.pack("<I", len(payload))
    out += payload
    return b"\x00\x01\x00\x00" + bytes(out)


def encode_frame_cdr(image: np.ndarray, *, stamp_ns: int, frame_id: str = "", codec: str = "jpeg",
                     quality: int = DEFAULT_JPEG_QUALITY) -> bytes:
    """Compress a uint8 BGR (H, W, 3) or grey (H, W) image and return the CDR bytes of its
    ``CompressedImage`` (image_transport's format string), e.g. to write into a bag with
    ``writer.write(compressed_topic(topic), cdr, log_ns, msg_type=COMPRESSED_IMAGE_TYPE)``."""
    fmt, data = encode_compressed(image, codec=codec, quality=quality)
    return compressed_image_cdr(stamp_ns=stamp_ns, frame_id=frame_id, fmt=fmt, data=data)


class _Reader:
    def __init__(self, buf):
        self.buf = memoryview(buf).cast("B")
        if len(self.buf) < 4 or self.buf[0] != 0 or self.buf[1] not in (0, 1):
            raise ImageError("compressed image message is not CDR (bad encapsulation header)")
        self.order = "<" if self.buf[1] == 1 else ">"
        self.pos = 4

    def take(self, n: int, align: int = 1) -> memoryview:
        self.pos += (-(self.pos - 4)) % align
        if n < 0 or self.pos + n > len(self.buf):
            raise ImageError(f"compressed image message is cut short ({len(self.buf)} bytes)")
        out = self.buf[self.pos:self.pos + n]
        self.pos += n
        return out

    def u32(self, signed: bool = False) -> int:
        return struct.unpack(self.order + ("i" if signed else "I"), self.take(4, 4))[0]

    def string(self) -> str:
        raw = bytes(self.take(self.u32()))
        return (raw[:-1] if raw.endswith(b"\0") else raw).decode("utf-8", "replace")


def parse_compressed_image_cdr(data) -> CompressedFrame:
    """Read the CDR bytes of a ``sensor_msgs/msg/CompressedImage`` (the data is a view, not
    a copy). Raises :class:`ImageError` for bytes that are not a complete message."""
    r = _Reader(data)
    sec, nsec = r.u32(signed=True), r.u32()
    frame_id = r.string()
    fmt = r.string()
    payload = r.take(r.u32())
    return CompressedFrame(sec * _NS + nsec, frame_id, fmt, payload)


def add_compression_arguments(p) -> None:
    """``--compress-images`` and ``--jpeg-quality`` (bag_record, run, canopy_graph)."""
    p.add_argument("--compress-images", action="store_true",
                   help="store 8-bit images as <topic>/compressed (sensor_msgs/CompressedImage: JPEG, "
                        "PNG for masks; depth stays raw), as image_transport names them")
    p.add_argument("--jpeg-quality", type=int, default=DEFAULT_JPEG_QUALITY, metavar="Q",
                   help=f"JPEG quality 1-100 of --compress-images (default {DEFAULT_JPEG_QUALITY})")
