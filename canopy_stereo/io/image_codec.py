"""Compressed camera images (JPEG, PNG) as ROS carries them, decoded and encoded.

``sensor_msgs/CompressedImage`` says what its bytes are in a free-form ``format``
string, and drivers fill it differently:

* image_transport's ``compressed`` plugin: ``"<raw encoding>; <codec> compressed <encoding>"``,
  e.g. ``"bgr8; jpeg compressed bgr8"``, ``"rgb8; jpeg compressed bgr8"``,
  ``"mono8; jpeg compressed mono8"``, ``"bgr8; png compressed bgr8"``;
* usb_cam, gscam, depthai and many ROS 1 drivers: plain ``"jpeg"`` / ``"png"``
  (also ``"jpg"``, ``"mjpeg"``, upper case);
* web-style MIME types: ``"image/jpeg"``, ``"image/png"``;
* empty: nothing said.

:func:`decode_compressed` accepts all of them and lets the bytes decide (JPEG and PNG
announce themselves in their first bytes): a frame is decoded once, to the uint8 BGR
(H, W, 3) the rest of the pipeline takes, whatever the sender's channel order (a
``"rgb8; jpeg compressed bgr8"`` JPEG holds ordinary JPEG colour; only the encoding of the
sender's raw image was rgb8). EXIF orientation is ignored: a camera frame is used as
captured. Damaged data (a JPEG cut short, bytes that are neither JPEG nor PNG, a
``compressedDepth`` image) raises :class:`~canopy_stereo.errors.ImageError` with the reason.

:func:`encode_compressed` writes what image_transport's compressed publisher writes
(JPEG at ``quality``, default 95 as image_transport's ``jpeg_quality``; or PNG), with its
``format`` string. No ROS import here: nodes, bag readers and the simulator share it.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import ImageError

#: Codecs a CompressedImage may carry here.
CODECS = ("jpeg", "png")

#: image_transport's default JPEG quality (``jpeg_quality``), 1-100.
DEFAULT_JPEG_QUALITY = 95

#: The ``format`` of a device's own MJPEG frames (image_transport form: the JPEG decodes to BGR).
DEVICE_JPEG_FORMAT = "bgr8; jpeg compressed bgr8"

#: 8-bit raw encodings a compressed camera image may declare (16-bit and float ones are depth).
EIGHT_BIT_ENCODINGS = ("bgr8", "rgb8", "bgra8", "rgba8", "mono8", "8uc1", "8uc3", "8uc4")

_JPEG_MAGIC = b"\xff\xd8\xff"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"
_CODEC_NAMES = {"jpeg": "jpeg", "jpg": "jpeg", "mjpeg": "jpeg", "mjpg": "jpeg", "png": "png"}
_READ_FLAGS = cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION
_GREY_FLAGS = cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION


@dataclass(frozen=True)
class CompressedFormat:
    """What a ``format`` string says.

    Attributes:
        codec: ``"jpeg"``, ``"png"`` or None (not said: the bytes tell).
        encoding: the sender's raw encoding before compression (``"bgr8"``, ``"rgb8"``,
            ``"mono8"``, ...), lower case, or None when not said.
    """

    codec: str | None
    encoding: str | None


def parse_format(fmt: str) -> CompressedFormat:
    """Read a CompressedImage ``format`` string (any of the forms in the module docstring).

    Raises :class:`ImageError` for ``compressedDepth`` (a depth image, not a camera frame),
    a declared raw encoding that is not 8-bit, and codecs other than JPEG and PNG.
    """
    text = (fmt or "").strip().lower()
    encoding = None
    if ";" in text:
        encoding, rest = (part.strip() for part in text.split(";", 1))
        words = rest.replace("compressed", " ").split()
        if "compresseddepth" in rest.replace(" ", ""):
            raise ImageError(f"format {fmt!r} is image_transport's compressedDepth (a depth image), "
                             "not a camera frame")
        codec = next((_CODEC_NAMES[w] for w in words if w in _CODEC_NAMES), None)
        if codec is None:
            raise ImageError(f"unsupported compressed image format {fmt!r}: the codec must be "
                             f"{' or '.join(CODECS)}")
        if encoding and encoding not in EIGHT_BIT_ENCODINGS:
            raise ImageError(f"compressed image of encoding {encoding!r} (format {fmt!r}) is not an "
                             "8-bit colour or mono camera image")
        return CompressedFormat(codec, encoding or None)
    if text.startswith("image/"):
        text = text[len("image/"):]
    if not text:
        return CompressedFormat(None, None)
    if text not in _CODEC_NAMES:
        raise ImageError(f"unsupported compressed image format {fmt!r}: expected jpeg or png "
                         "(plain, image/<codec> or image_transport's '<encoding>; <codec> compressed "
                         "<encoding>')")
    return CompressedFormat(_CODEC_NAMES[text], None)


def sniff_codec(data) -> str | None:
    """``"jpeg"`` or ``"png"`` from the first bytes of ``data``, else None."""
    head = bytes(memoryview(data)[:8])
    if head.startswith(_JPEG_MAGIC):
        return "jpeg"
    if head.startswith(_PNG_MAGIC):
        return "png"
    return None


def _check_complete(buf: np.ndarray, codec: str) -> None:
    """A JPEG ends with its EOI marker (trailing zero padding allowed), a PNG with IEND."""
    tail = bytes(buf[-64:]).rstrip(b"\0")
    if codec == "jpeg" and not tail.endswith(b"\xff\xd9"):
        raise ImageError(f"corrupt JPEG: cut short (no end-of-image marker; {buf.size} bytes)")
    if codec == "png" and not tail.endswith(_PNG_END):
        raise ImageError(f"corrupt PNG: cut short (no IEND chunk; {buf.size} bytes)")


def decode_compressed(data, fmt: str = "", *, expected_size=None, grey: bool = False) -> np.ndarray:
    """Decode a compressed camera frame to uint8 BGR (H, W, 3) (``grey``: uint8 (H, W)).

    Args:
        data: the message's ``data`` (bytes, bytearray, memoryview, ``array('B')`` or a uint8 array).
        fmt: its ``format`` string (any form of the module docstring; empty: sniffed).
        expected_size: ``(width, height)`` the frame must have, or None.
        grey: decode to one grey channel (a mono8 image, a mask) instead of BGR.

    Raises :class:`ImageError` naming the problem: empty data, bytes that are neither JPEG
    nor PNG, a frame cut short or that the decoder rejects, a size other than ``expected_size``.
    """
    parse_format(fmt)  # rejects depth and non-image formats with their reason
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1)
    if buf.size == 0:
        raise ImageError("compressed image has no data")
    codec = sniff_codec(buf[:8])
    if codec is None:
        raise ImageError(f"compressed image (format {fmt!r}) is neither JPEG nor PNG "
                         f"(first bytes {bytes(buf[:4]).hex()})")
    _check_complete(buf, codec)
    image = cv2.imdecode(buf, _GREY_FLAGS if grey else _READ_FLAGS)
    if image is None or image.size == 0:
        raise ImageError(f"corrupt {codec.upper()}: the decoder rejected it ({buf.size} bytes)")
    h, w = image.shape[:2]
    if expected_size is not None and (w, h) != tuple(expected_size):
        raise ImageError(f"image is {w}x{h} but {expected_size[0]}x{expected_size[1]} is expected")
    return image


def encode_compressed(image: np.ndarray, *, codec: str = "jpeg", quality: int = DEFAULT_JPEG_QUALITY,
                      png_level: int = 1) -> tuple[str, bytes]:
    """Compress a uint8 BGR (H, W, 3) or grey (H, W) image as image_transport's publisher does.

    Args:
        image: uint8 (H, W) mono or (H, W, 3) BGR.
        codec: ``"jpeg"`` or ``"png"``.
        quality: JPEG quality, 1-100.
        png_level: PNG compression level, 0-9 (1: fast, image_transport's default is 3).

    Returns ``(format, bytes)``, ``format`` in image_transport's form, e.g.
    ``"bgr8; jpeg compressed bgr8"``.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] in (1, 3))):
        raise ImageError(f"only uint8 grey (H, W) or BGR (H, W, 3) images are compressed, got "
                         f"{image.dtype} {image.shape}")
    if codec not in CODECS:
        raise ImageError(f"codec must be one of {', '.join(CODECS)}, got {codec!r}")
    if not 1 <= int(quality) <= 100:
        raise ImageError(f"JPEG quality must be in 1..100, got {quality}")
    encoding = "mono8" if image.ndim == 2 or image.shape[2] == 1 else "bgr8"
    params = ([cv2.IMWRITE_JPEG_QUALITY, int(quality)] if codec == "jpeg"
              else [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)])
    ok, buf = cv2.imencode(".jpg" if codec == "jpeg" else ".png", np.ascontiguousarray(image), params)
    if not ok:
        raise ImageError(f"{codec.upper()} encoding of a {image.shape} image failed")
    return f"{encoding}; {codec} compressed {encoding}", buf.tobytes()
