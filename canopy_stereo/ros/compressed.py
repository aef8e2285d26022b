"""``sensor_msgs/CompressedImage`` messages <-> arrays, image_transport's conventions.

The codec (formats, JPEG/PNG, corrupt data) is :mod:`canopy_stereo.io.image_codec`;
this module only moves bytes in and out of rclpy messages. Topic names follow
image_transport: the compressed stream of ``left/image_raw`` is
``left/image_raw/compressed`` (:func:`~canopy_stereo.io.compressed_image.compressed_topic`);
a node's ``image_transport`` parameter (``raw`` or ``compressed``, as stereo_image_proc's
in Jazzy) chooses which it subscribes to (:func:`input_topic`).
"""
from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import CompressedImage, Image

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.compressed_image import COMPRESSED_IMAGE_TYPE, IMAGE_TYPE, compressed_topic
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY, decode_compressed, encode_compressed, parse_format
from canopy_stereo.ros.convert import COLOUR_ENCODINGS, image_to_msg, make_header, msg_to_bgr, msg_to_image
from canopy_stereo.ros.limits import MAX_IMAGE_BYTES

#: Values of the ``image_transport`` parameter.
TRANSPORTS = ("raw", "compressed")


def input_topic(base_topic: str, transport: str) -> str:
    """The topic a subscriber with ``image_transport`` = ``transport`` reads for ``base_topic``."""
    if transport not in TRANSPORTS:
        raise CanopyStereoError(f"image_transport must be {' or '.join(TRANSPORTS)}, got {transport!r}")
    return base_topic if transport == "raw" else compressed_topic(base_topic)


def compressed_msg(data, fmt: str, *, stamp_ns: int = 0, frame_id: str = "") -> CompressedImage:
    """A ``CompressedImage`` holding ``data`` (bytes or a uint8 array: one copy) with ``format`` ``fmt``."""
    msg = CompressedImage(header=make_header(stamp_ns, frame_id), format=fmt)
    payload = array.array("B")
    payload.frombytes(np.asarray(data, dtype=np.uint8).reshape(-1) if isinstance(data, np.ndarray) else data)
    msg.data = payload  # assigned, not passed to the constructor: one block copy
    return msg


def image_to_compressed_msg(image: np.ndarray, *, codec: str = "jpeg", quality: int = DEFAULT_JPEG_QUALITY,
                            stamp_ns: int = 0, frame_id: str = "") -> CompressedImage:
    """Compress a uint8 BGR (H, W, 3) or grey (H, W) image into a ``CompressedImage``
    (image_transport's format string, e.g. ``"bgr8; jpeg compressed bgr8"``)."""
    fmt, data = encode_compressed(image, codec=codec, quality=quality)
    return compressed_msg(data, fmt, stamp_ns=stamp_ns, frame_id=frame_id)


def compressed_msg_to_bgr(msg: CompressedImage, expected_size=None, *, grey: bool = False) -> np.ndarray:
    """Decode a ``CompressedImage`` (any format of :mod:`canopy_stereo.io.image_codec`) to
    uint8 BGR (H, W, 3), or with ``grey`` to uint8 grey (H, W) (a JPEG's luma straight from the
    decoder, without the colour conversion); :class:`ImageError` with the reason for damaged data
    or a wrong size."""
    n = len(msg.data)
    if n > MAX_IMAGE_BYTES:
        raise ImageError(f"compressed image of {n} bytes is larger than {MAX_IMAGE_BYTES} bytes")
    return decode_compressed(msg.data, msg.format, expected_size=expected_size, grey=grey)


def recording_codec(topic: str) -> str:
    """Codec of a recorded image topic: PNG (lossless) for masks, whose pixels are labels;
    JPEG for camera images."""
    return "png" if topic.rstrip("/").endswith("mask") else "jpeg"


def compress_image_cdr(data, *, codec: str = "jpeg", quality: int = DEFAULT_JPEG_QUALITY) -> bytes | None:
    """CDR bytes of a ``sensor_msgs/Image`` -> CDR bytes of its ``CompressedImage`` (same
    header; image_transport's format string), or None when the image is not 8-bit colour or
    mono (e.g. a 32FC1 depth image: JPEG and 8-bit PNG cannot hold it)."""
    from rclpy.serialization import deserialize_message, serialize_message

    msg = deserialize_message(bytes(data), Image)
    if msg.encoding not in COLOUR_ENCODINGS:
        return None
    image = msg_to_image(msg, COLOUR_ENCODINGS)
    image = msg_to_bgr(msg) if image.ndim == 3 else image
    out = image_to_compressed_msg(image, codec=codec, quality=quality)
    out.header = msg.header
    return serialize_message(out)


class RecordingCompression:
    """Store ``sensor_msgs/Image`` topics compressed while recording: each 8-bit image goes to
    image_transport's ``<topic>/compressed`` as a ``CompressedImage`` (JPEG at ``quality``;
    PNG for masks, :func:`recording_codec`); other images (depth) stay raw on ``<topic>``.

    :meth:`convert` maps one recorded message ``(topic, type, CDR)`` to what is written.
    """

    def __init__(self, *, quality: int = DEFAULT_JPEG_QUALITY):
        if not 1 <= int(quality) <= 100:
            raise CanopyStereoError(f"JPEG quality must be in 1..100, got {quality}")
        self.quality = int(quality)

    def convert(self, topic: str, type_name: str, data) -> tuple[str, str, bytes]:
        """``(topic, type, CDR)`` to write for a message received on ``topic``."""
        if type_name != IMAGE_TYPE:
            return topic, type_name, data
        packed = compress_image_cdr(data, codec=recording_codec(topic), quality=self.quality)
        if packed is None:
            return topic, type_name, data
        return compressed_topic(topic), COMPRESSED_IMAGE_TYPE, packed


def decompress_image_cdr(data) -> bytes:
    """CDR bytes of a ``CompressedImage`` -> CDR bytes of the ``sensor_msgs/Image`` it holds
    (same header): mono8 when its format says mono8 (masks), else bgr8."""
    from rclpy.serialization import deserialize_message, serialize_message

    msg = deserialize_message(bytes(data), CompressedImage)
    grey = parse_format(msg.format).encoding in ("mono8", "8uc1")
    image = decode_compressed(msg.data, msg.format, grey=grey)
    out = image_to_msg(image, "mono8" if grey else "bgr8")
    out.header = msg.header
    return serialize_message(out)


def compression_from_args(args):
    """The :class:`~canopy_stereo.ros.compressed.RecordingCompression` the options ask for, or None."""
    if not getattr(args, "compress_images", False):
        return None
    return RecordingCompression(quality=args.jpeg_quality)
