"""Stereo frames of a bag (raw or compressed images), read without ROS.

Batch workers run on machines that may have only the core installed (a
cluster's Python environment rarely has ROS 2), so this module decodes
``sensor_msgs/msg/Image`` from its CDR bytes itself and pairs the left and
right streams with :class:`~canopy_stereo.bag.pairing.ApproximateTimePairer`, the
pairing the rectify node applies live. The bag is read by
:class:`~canopy_stereo.bag.BagReader` (the ``mcap`` package, no rclpy).

CDR layout of ``sensor_msgs/msg/Image`` after the 4-byte encapsulation header
(``00 01`` little-endian, ``00 00`` big-endian; alignment counted from the end
of that header): ``int32 sec, uint32 nanosec, string frame_id, uint32 height,
uint32 width, string encoding, uint8 is_bigendian, uint32 step,
sequence<uint8> data`` (strings and sequences: ``uint32`` length, then the
bytes; strings include their terminating NUL).

A bag holding only compressed images (``sensor_msgs/msg/CompressedImage``, JPEG or PNG, on
image_transport's ``<topic>/compressed``) is read the same way: :func:`stereo_topics` finds
them when the raw topics are absent, and :func:`image_to_bgr` decodes either kind
(:mod:`canopy_stereo.io.compressed_image`).
"""
from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.compressed_image import (
    COMPRESSED_IMAGE_TYPE,
    CompressedFrame,
    compressed_topic,
    parse_compressed_image_cdr,
)

#: Default stereo topics of canopy_stereo's raw recordings.
LEFT_TOPIC = "/stereo/left/image_raw"
RIGHT_TOPIC = "/stereo/right/image_raw"
IMAGE_TYPE = "sensor_msgs/msg/Image"

#: 8-bit encodings converted to BGR (as :func:`canopy_stereo.ros.convert.msg_to_bgr`).
_CHANNELS = {"bgr8": 3, "rgb8": 3, "8UC3": 3, "bgra8": 4, "rgba8": 4, "8UC4": 4, "mono8": 1, "8UC1": 1}
_TO_BGR = {"rgb8": cv2.COLOR_RGB2BGR, "rgba8": cv2.COLOR_RGBA2BGR, "bgra8": cv2.COLOR_BGRA2BGR,
           "8UC4": cv2.COLOR_BGRA2BGR, "mono8": cv2.COLOR_GRAY2BGR, "8UC1": cv2.COLOR_GRAY2BGR}


@dataclass(frozen=True)
class RawImage:
    """A decoded ``sensor_msgs/msg/Image``: header stamp (ns), frame, size, encoding
    and the pixel bytes (``step * height`` bytes, rows possibly padded)."""

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    encoding: str
    is_bigendian: bool
    step: int
    data: memoryview


class _Cursor:
    def __init__(self, buf: bytes):
        if len(buf) < 4 or buf[0] != 0 or buf[1] not in (0, 1):
            raise ImageError("image message is not CDR (bad encapsulation header)")
        self.buf = memoryview(buf)
        self.order = "<" if buf[1] == 1 else ">"
        self.pos = 4

    def _align(self, n: int) -> None:
        self.pos += (-(self.pos - 4)) % n

    def _take(self, n: int) -> memoryview:
        if n < 0 or self.pos + n > len(self.buf):
            raise ImageError(f"image message is cut short ({len(self.buf)} bytes)")
        out = self.buf[self.pos:self.pos + n]
        self.pos += n
        return out

    def u32(self) -> int:
        self._align(4)
        return struct.unpack(self.order + "I", self._take(4))[0]

    def i32(self) -> int:
        self._align(4)
        return struct.unpack(self.order + "i", self._take(4))[0]

    def u8(self) -> int:
        return self._take(1)[0]

    def string(self) -> str:
        n = self.u32()
        raw = bytes(self._take(n))
        return raw[:-1].decode("utf-8", "replace") if raw.endswith(b"\0") else raw.decode("utf-8", "replace")

    def octets(self) -> memoryview:
        return self._take(self.u32())


def decode_image(data: bytes) -> RawImage:
    """Decode the CDR bytes of a ``sensor_msgs/msg/Image`` (raises :class:`ImageError`
    for bytes that are not a complete image message)."""
    c = _Cursor(data)
    sec, nsec = c.i32(), c.u32()
    frame_id = c.string()
    height, width = c.u32(), c.u32()
    encoding = c.string()
    big = bool(c.u8())
    step = c.u32()
    pixels = c.octets()
    return RawImage(sec * 1_000_000_000 + nsec, frame_id, height, width, encoding, big, step, pixels)


def image_to_bgr(img: RawImage | CompressedFrame) -> np.ndarray:
    """uint8 BGR (H, W, 3) of an 8-bit colour or mono image (:class:`ImageError` otherwise,
    or when the data is shorter than ``step * height``), or of a compressed one (decoded;
    :class:`ImageError` when it is corrupt)."""
    if isinstance(img, CompressedFrame):
        return img.to_bgr()
    channels = _CHANNELS.get(img.encoding)
    if channels is None:
        raise ImageError(f"image encoding {img.encoding!r} is not an 8-bit colour or mono image; "
                         f"expected one of {', '.join(_CHANNELS)}")
    h, w, step = img.height, img.width, img.step
    if h == 0 or w == 0:
        raise ImageError(f"empty image ({w}x{h})")
    row = w * channels
    if step < row:
        raise ImageError(f"image step {step} is smaller than a row ({row} bytes)")
    if len(img.data) < step * h:
        raise ImageError(f"image data has {len(img.data)} bytes, {step * h} expected for {w}x{h} {img.encoding}")
    buf = np.frombuffer(img.data, np.uint8, count=step * h).reshape(h, step)[:, :row]
    arr = np.ascontiguousarray(buf).reshape((h, w) if channels == 1 else (h, w, channels))
    code = _TO_BGR.get(img.encoding)
    return cv2.cvtColor(arr, code) if code is not None else arr


def stereo_topics(bag, left_topic: str = LEFT_TOPIC, *, right_topic: str = RIGHT_TOPIC) -> tuple[str, str]:
    """The bag's topics for the stereo pair: ``left_topic`` and ``right_topic`` when the bag has
    them, else their image_transport ``/compressed`` topics when it has those (a bag holding
    only compressed images), else the given ones (:func:`raw_stereo_pairs` then names them)."""
    if left_topic in bag.topics and right_topic in bag.topics:
        return left_topic, right_topic
    packed = compressed_topic(left_topic), compressed_topic(right_topic)
    return packed if all(t in bag.topics for t in packed) else (left_topic, right_topic)


def raw_stereo_pairs(bag, left_topic: str = LEFT_TOPIC, *, right_topic: str = RIGHT_TOPIC,
                     slop_s: float = 0.015) -> Iterator[tuple[int, RawImage | CompressedFrame,
                                                          RawImage | CompressedFrame]]:
    """``(stamp_ns, left, right)`` pairs of ``bag`` (a :class:`~canopy_stereo.bag.BagReader`):
    :class:`RawImage` for ``sensor_msgs/msg/Image`` topics, still-compressed
    :class:`~canopy_stereo.io.compressed_image.CompressedFrame` for ``CompressedImage`` ones
    (decoded by :func:`image_to_bgr` only for the pairs used), paired by nearest header stamp
    within ``slop_s`` seconds (:class:`~canopy_stereo.bag.pairing.ApproximateTimePairer`); the
    pair's stamp is the left image's. Raises :class:`ImageError` when a topic is missing or
    not an image."""
    for topic in (left_topic, right_topic):
        info = bag.topics.get(topic)
        if info is None:
            raise ImageError(f"the bag has no {topic} (topics: {', '.join(sorted(bag.topics)) or 'none'})")
        if info.type_name not in (IMAGE_TYPE, COMPRESSED_IMAGE_TYPE):
            raise ImageError(f"{topic} is {info.type_name}, not {IMAGE_TYPE} or {COMPRESSED_IMAGE_TYPE}")
    from canopy_stereo.bag.pairing import ApproximateTimePairer

    compressed = {t for t in (left_topic, right_topic) if bag.topics[t].type_name == COMPRESSED_IMAGE_TYPE}
    pairer = ApproximateTimePairer(slop_s, queue_size=5)
    for m in bag.messages([left_topic, right_topic]):
        img = parse_compressed_image_cdr(m.data) if m.topic in compressed else decode_image(m.data)
        pair, _ = pairer.push(0 if m.topic == left_topic else 1, img.stamp_ns, img)
        if pair is not None:
            left, right = pair.items
            yield left.stamp_ns, left, right


def stereo_pairs(bag, left_topic: str = LEFT_TOPIC, *, right_topic: str = RIGHT_TOPIC,
                 slop_s: float = 0.015) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """``(stamp_ns, left_bgr, right_bgr)`` for each pair of :func:`raw_stereo_pairs`."""
    for stamp, left, right in raw_stereo_pairs(bag, left_topic, right_topic=right_topic, slop_s=slop_s):
        yield stamp, image_to_bgr(left), image_to_bgr(right)
