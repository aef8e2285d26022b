"""One captured frame -> what a camera driver publishes: per side, the image and/or its JPEG.

Pure core of ``camera_node`` (no ROS). A capture is either a decoded image (uint8 BGR or
grey) or, when a device delivers MJPEG and is asked not to convert it, the device's own
JPEG bytes (OpenCV returns them as a (1, N) uint8 row). :func:`prepare_frame` turns it into
what the ``layout`` and ``transport`` ask for:

* ``layout``: ``mono`` (one camera), ``side_by_side`` (left view in the left half, right
  view in the right half: the synchronized one-USB-device stereo webcams) or
  ``top_bottom`` (left on top); both views of a stereo layout come from one exposure,
  so they share one stamp;
* ``transport``: ``raw`` (images), ``compressed`` (JPEG) or ``both``.

It decodes and encodes as little as possible: a device's JPEG of a ``mono`` layout goes out
as it came (no decode unless raw images are wanted too, no re-encode); a stereo layout
needs the pixels to split them, so its halves are encoded at ``quality``; so are decoded
captures (video files, image sequences, raw devices).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.image_codec import DEVICE_JPEG_FORMAT, decode_compressed, encode_compressed, sniff_codec

#: Values of ``camera_node``'s ``layout`` parameter.
LAYOUTS = ("mono", "side_by_side", "top_bottom")

#: Values of ``camera_node``'s ``transport`` parameter.
CAMERA_TRANSPORTS = ("raw", "compressed", "both")


@dataclass(frozen=True)
class SideFrame:
    """What one side publishes for a capture.

    Attributes:
        side: index of the view (0 = left or the mono camera, 1 = right).
        image: uint8 BGR (H, W, 3), or None when only compressed output is wanted.
        compressed: ``(format, JPEG bytes)``, or None when only raw output is wanted.
        shape: (H, W) of the view.
    """

    side: int
    image: np.ndarray | None
    compressed: tuple[str, bytes] | None
    shape: tuple[int, int]


def is_encoded(frame: np.ndarray) -> bool:
    """True for a capture that is a device's JPEG bytes (a 1-row or flat uint8 buffer)."""
    return (frame.dtype == np.uint8 and (frame.ndim == 1 or (frame.ndim == 2 and frame.shape[0] == 1))
            and sniff_codec(frame.reshape(-1)[:8]) == "jpeg")


def _bgr(frame: np.ndarray) -> np.ndarray:
    import cv2

    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2BGR)
    return frame


def split_views(image: np.ndarray, layout: str) -> list[np.ndarray]:
    """The views of one capture: ``[image]`` for ``mono``, ``[left, right]`` halves (views,
    no copy) for ``side_by_side`` (split across the width) and ``top_bottom`` (across the height).

    Raises :class:`ImageError` for an unknown layout or an odd width/height to split.
    """
    if layout not in LAYOUTS:
        raise ImageError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    if layout == "mono":
        return [image]
    h, w = image.shape[:2]
    axis, n = (1, w) if layout == "side_by_side" else (0, h)
    if n % 2:
        raise ImageError(f"a {layout} frame needs an even {'width' if axis else 'height'}, got {w}x{h}")
    half = n // 2
    return [image[:, :half], image[:, half:]] if axis else [image[:half], image[half:]]


def prepare_frame(frame: np.ndarray, *, layout: str = "mono", transport: str = "raw",
                  quality: int = 95) -> list[SideFrame]:
    """Per view of ``frame``, the raw image and/or JPEG to publish (see the module docstring).

    Args:
        frame: a decoded capture (uint8 (H, W), (H, W, 3) BGR or (H, W, 4) BGRA) or a
            device's JPEG bytes (:func:`is_encoded`).
        layout: one of :data:`LAYOUTS`.
        transport: one of :data:`CAMERA_TRANSPORTS`.
        quality: JPEG quality (1-100) of what is encoded here.
    """
    if transport not in CAMERA_TRANSPORTS:
        raise ImageError(f"transport must be one of {', '.join(CAMERA_TRANSPORTS)}, got {transport!r}")
    want_raw, want_jpeg = transport in ("raw", "both"), transport in ("compressed", "both")
    if is_encoded(frame):
        data = frame.reshape(-1)
        if layout == "mono":  # the device's bytes as they came; decoded only for a raw image
            decoded = decode_compressed(data, DEVICE_JPEG_FORMAT) if want_raw else None
            shape = decoded.shape[:2] if decoded is not None else _jpeg_shape(data)
            return [SideFrame(0, decoded, (DEVICE_JPEG_FORMAT, data.tobytes()) if want_jpeg else None, shape)]
        frame = decode_compressed(data, DEVICE_JPEG_FORMAT)
    views = split_views(_bgr(frame), layout)
    out = []
    for side, view in enumerate(views):
        view = np.ascontiguousarray(view)
        jpeg = encode_compressed(view, codec="jpeg", quality=quality) if want_jpeg else None
        out.append(SideFrame(side, view if want_raw else None, jpeg, view.shape[:2]))
    return out


def _jpeg_shape(data: np.ndarray) -> tuple[int, int]:
    """(H, W) from a JPEG's start-of-frame marker, without decoding it."""
    buf = data.tobytes()
    i = 2
    while i + 9 < len(buf):
        if buf[i] != 0xFF:
            i += 1
            continue
        marker = buf[i + 1]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            return int.from_bytes(buf[i + 5:i + 7], "big"), int.from_bytes(buf[i + 7:i + 9], "big")
        if marker == 0xFF or marker in (0x01, *range(0xD0, 0xD8)):
            i += 1 if marker == 0xFF else 2
            continue
        i += 2 + int.from_bytes(buf[i + 2:i + 4], "big")
    raise ImageError("JPEG from the device has no frame header (corrupt)")
