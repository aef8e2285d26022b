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
from sensor_msgs.msg import CompressedImage

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.compressed_image import compressed_topic
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY, decode_compressed, encode_compressed
from canopy_stereo.ros.convert import make_header
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


def compressed_msg_to_bgr(msg: CompressedImage, expected_size=None) -> np.ndarray:
    """Decode a ``CompressedImage`` (any format of :mod:`canopy_stereo.io.image_codec`) to
    uint8 BGR (H, W, 3); :class:`ImageError` with the reason for damaged data or a wrong size."""
    n = len(msg.data)
    if n > MAX_IMAGE_BYTES:
        raise ImageError(f"compressed image of {n} bytes is larger than {MAX_IMAGE_BYTES} bytes")
    return decode_compressed(msg.data, msg.format, expected_size=expected_size)
