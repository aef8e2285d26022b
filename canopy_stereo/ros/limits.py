"""Message limits of the nodes: what an incoming message may be before anything is allocated.

A node receives whatever a publisher sends: an 8000x8000 frame, a 1x1 image, a
header that claims more bytes than it carries, a disparity image full of NaN.
Each node checks the message's *header fields* (width, height, step, encoding,
length of ``data``) against what it expects -- the rig's image size, or for the
nodes without a rig a hard maximum -- **before** decoding it into numpy arrays,
so a hostile message costs no more than the bytes the middleware already
delivered. A refused message raises :class:`~canopy_stereo.errors.ImageError`
with the reason; the node's ``drop()`` logs it (rate-limited) and counts it.

After a large message has been refused, :func:`release_memory_soon` hands the
freed memory back to the operating system once the callback has returned (and
for a few seconds after, as the middleware's threads free their buffers), so
one hostile burst does not leave the process large (see
:func:`canopy_stereo.ros.context.tune_memory_allocator` and
:func:`~canopy_stereo.ros.context.release_free_memory`).

Limits (all checked on the header, in this order):

* encoding: known (:data:`~canopy_stereo.ros.convert.ENCODINGS`) and accepted by the node;
* size: not empty, at least ``min_size``, at most :data:`MAX_IMAGE_PIXELS` and exactly
  the ``expected_size`` (the rig's) when the node has one;
* layout: ``step`` at least one row and at most :data:`MAX_IMAGE_BYTES` for the image,
  ``len(data) == step * height`` (the definition of ``sensor_msgs/Image``);
* disparity images: ``f``, ``t``, ``min_disparity``, ``max_disparity``, ``delta_d``
  finite, ``min_disparity < max_disparity``, and every pixel finite (invalid pixels are
  marked *below* ``min_disparity`` in ``stereo_msgs/DisparityImage``, never NaN or inf).
"""
from __future__ import annotations

import math
import threading

import numpy as np

from canopy_stereo.disparity.wire import count_nonfinite
from canopy_stereo.errors import ImageError
from canopy_stereo.ros.convert import ENCODINGS

#: Largest image any node accepts, in pixels (16.8 Mpx = 4096 x 4096; webcams give <= 8.3 Mpx).
MAX_IMAGE_PIXELS = 4096 * 4096

#: Largest image payload any node accepts, in bytes (a 4096 x 4096 4-channel 8-bit or
#: 1-channel float image, with row padding up to 2x).
MAX_IMAGE_BYTES = 128 << 20

#: Smallest image ``segment_node`` (which has no rig) accepts: GrabCut's colour models need
#: some hundreds of pixels at the node's processing scale.
SEGMENT_MIN_SIZE = (32, 32)

#: A refused message of at least this many bytes (header claim or payload) triggers
#: :func:`release_memory_soon`: the middleware and rclpy allocated it on the heap (below the
#: 32 MiB mmap threshold of :func:`~canopy_stereo.ros.context.tune_memory_allocator`), where
#: the freed space would otherwise stay with the process.
TRIM_AFTER_BYTES = 4 << 20


def image_msg_bytes(msg) -> int:
    """Bytes of the ``data`` field of a ``sensor_msgs/Image`` (no copy)."""
    return len(msg.data)


def _short(text: str, limit: int = 40) -> str:
    """``text`` cut to ``limit`` characters for a log line (a hostile field can be megabytes)."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def check_image_msg(msg, *, expected_size=None, encodings=None, min_size=(1, 1),
                    max_pixels: int = MAX_IMAGE_PIXELS, max_bytes: int = MAX_IMAGE_BYTES) -> None:
    """Refuse a ``sensor_msgs/Image`` from its header alone (nothing is decoded or copied).

    Args:
        msg: the message.
        expected_size: ``(width, height)`` it must have (the rig's), or None.
        encodings: accepted encodings (None: any known one).
        min_size: smallest ``(width, height)`` the node can use.
        max_pixels, max_bytes: hard maxima (:data:`MAX_IMAGE_PIXELS`, :data:`MAX_IMAGE_BYTES`).

    Raises :class:`~canopy_stereo.errors.ImageError` naming the problem. An oversize
    message also schedules :func:`release_memory_soon`.
    """
    try:
        _check_image(msg, expected_size, encodings, min_size, max_pixels, max_bytes)
    except ImageError:
        claimed = int(msg.step) * int(msg.height)
        if max(claimed, image_msg_bytes(msg)) >= TRIM_AFTER_BYTES:
            release_memory_soon()
        raise


def _check_image(msg, expected_size, encodings, min_size, max_pixels, max_bytes) -> None:
    enc = msg.encoding
    if enc not in ENCODINGS:
        raise ImageError(f"unsupported image encoding {_short(enc)!r}")
    if encodings is not None and enc not in encodings:
        raise ImageError(f"image encoding {enc!r} not accepted here; expected one of {', '.join(encodings)}")
    w, h, step, n = int(msg.width), int(msg.height), int(msg.step), image_msg_bytes(msg)
    if w == 0 or h == 0:
        raise ImageError(f"empty image ({w}x{h})")
    if w * h > max_pixels:
        raise ImageError(f"image is {w}x{h} ({w * h / 1e6:.1f} Mpx), over the limit of "
                         f"{max_pixels / 1e6:.1f} Mpx")
    if expected_size is not None and (w, h) != tuple(expected_size):
        raise ImageError(f"image is {w}x{h} but {expected_size[0]}x{expected_size[1]} is expected")
    if w < min_size[0] or h < min_size[1]:
        raise ImageError(f"image is {w}x{h}, smaller than {min_size[0]}x{min_size[1]}")
    dtype, channels = ENCODINGS[enc]
    row_bytes = w * channels * np.dtype(dtype).itemsize
    if step < row_bytes:
        raise ImageError(f"image step {step} is smaller than a row ({row_bytes} bytes)")
    if step * h > max_bytes or n > max_bytes:
        raise ImageError(f"image data of {max(step * h, n) / 2**20:.0f} MiB is over the limit of "
                         f"{max_bytes / 2**20:.0f} MiB")
    if n != step * h:
        raise ImageError(f"image data has {n} bytes, {step * h} expected for {w}x{h} {enc} "
                         f"(step {step})")


def check_disparity_msg(msg, *, expected_size=None, max_pixels: int = MAX_IMAGE_PIXELS,
                        max_bytes: int = MAX_IMAGE_BYTES, pixels: bool = True) -> None:
    """Refuse a ``stereo_msgs/DisparityImage``: its image as :func:`check_image_msg` (32FC1),
    then non-finite or inconsistent scalar fields, then (``pixels``) non-finite pixels.

    The pixel scan reads the payload in place (a view, no copy) and runs only once the
    size is known to be the expected one; ``pixels`` False skips it, for a node that uses
    the message's header and size only (segment_node's ``follow_disparity``).
    """
    check_image_msg(msg.image, expected_size=expected_size, encodings=("32FC1",),
                    max_pixels=max_pixels, max_bytes=max_bytes)
    fields = {name: float(getattr(msg, name)) for name in ("f", "t", "min_disparity", "max_disparity",
                                                           "delta_d")}
    bad = [f"{k} = {v}" for k, v in fields.items() if not math.isfinite(v)]
    if bad:
        raise ImageError(f"disparity message has non-finite {', '.join(bad)}")
    if not fields["min_disparity"] < fields["max_disparity"]:
        raise ImageError(f"disparity message has min_disparity {fields['min_disparity']:g} >= "
                         f"max_disparity {fields['max_disparity']:g}")
    if not pixels:
        return
    img = msg.image
    dt = np.dtype("f4").newbyteorder(">" if img.is_bigendian else "<")
    rows = np.frombuffer(img.data, dtype=np.uint8).reshape(int(img.height), int(img.step))
    values = rows[:, : int(img.width) * 4].view(dt)
    n = count_nonfinite(values)  # one compiled pass over the payload in place
    if n:
        raise ImageError(f"disparity image holds {n} non-finite value(s) (NaN/inf); invalid pixels "
                         "must be below min_disparity (stereo_msgs/DisparityImage)")


def check_cloud_msg(msg, *, max_points: int = MAX_IMAGE_PIXELS, max_bytes: int = MAX_IMAGE_BYTES * 2) -> None:
    """Refuse a ``sensor_msgs/PointCloud2`` from its header alone: more than ``max_points``
    points (a cloud of one rig has at most one point per rectified pixel), a layout whose
    fields do not fit ``point_step``, or ``data`` that is not ``row_step * height`` bytes."""
    try:
        _check_cloud(msg, max_points, max_bytes)
    except ImageError:
        if max(len(msg.data), int(msg.row_step) * int(msg.height)) >= TRIM_AFTER_BYTES:
            release_memory_soon()
        raise


def _check_cloud(msg, max_points: int, max_bytes: int) -> None:
    h, w, step, row_step, n = (int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step),
                               len(msg.data))
    if w * h > max_points:
        raise ImageError(f"PointCloud2 has {w * h} points ({w}x{h}), over the limit of {max_points}")
    if n > max_bytes:
        raise ImageError(f"PointCloud2 data of {n / 2**20:.0f} MiB is over the limit of {max_bytes / 2**20:.0f} MiB")
    if step <= 0 or row_step < step * w:
        raise ImageError(f"PointCloud2 has point_step {step} and row_step {row_step} for width {w}")
    for f in msg.fields:
        size = _POINT_FIELD_BYTES.get(int(f.datatype), 0) * max(1, int(f.count))
        if int(f.offset) + size > step:
            raise ImageError(f"PointCloud2 field {_short(f.name)!r} (offset {f.offset}) does not fit a "
                             f"point of {step} bytes")
    if n != row_step * h:
        raise ImageError(f"PointCloud2 data has {n} bytes, {row_step * h} expected ({h} rows of {row_step})")


#: bytes of each ``sensor_msgs/PointField`` datatype (INT8 = 1 ... FLOAT64 = 8)
_POINT_FIELD_BYTES = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 8: 8}


# --------------------------------------------------------------------------- memory release

#: Seconds after a refused oversize message before the free memory is returned to the system
#: (the message is released by rclpy when the callback returns).
RELEASE_DELAY_S = 0.5

_release_lock = threading.Lock()
_release_pending = False


def release_memory_soon(delay_s: float = RELEASE_DELAY_S) -> bool:
    """Return free heap memory to the system ``delay_s`` from now, and keep returning it for
    :data:`RELEASE_HOLD_S` (:func:`canopy_stereo.ros.context.release_free_memory`).

    Calls while one release is pending are merged. Returns False off glibc.
    """
    global _release_pending
    from canopy_stereo.ros.context import malloc_trim_available

    if not malloc_trim_available():
        return False
    with _release_lock:
        if _release_pending:
            return True
        _release_pending = True
    timer = threading.Timer(delay_s, _release)
    timer.daemon = True
    timer.start()
    return True


#: Seconds the allocator keeps trimming every arena after a refused large message
#: (:func:`canopy_stereo.ros.context.release_free_memory`). A steady stream of refused large
#: messages keeps it trimming, at the cost of glibc's default speed (about 20 ms more system
#: time per frame on the development machine) until the stream stops.
RELEASE_HOLD_S = 10.0


def _release() -> None:
    global _release_pending
    from canopy_stereo.ros.context import release_free_memory

    with _release_lock:
        _release_pending = False
    release_free_memory(hold_s=RELEASE_HOLD_S)
