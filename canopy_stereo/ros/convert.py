"""Conversions between ROS messages and numpy arrays (a small ``cv_bridge``).

* :func:`image_to_msg` / :func:`msg_to_image`: ``sensor_msgs/Image`` <-> (H, W) or
  (H, W, C) arrays, with the encodings of ``sensor_msgs/image_encodings.hpp``.
* :func:`disparity_to_msg` / :func:`msg_to_disparity`: ``stereo_msgs/DisparityImage``
  (32FC1 image, ``f`` in pixels, ``t`` in metres, disparities reduced by the
  principal-point offset so that ``Z = f t / d``, invalid pixels below
  ``min_disparity``) <-> float32 disparity (NaN = invalid).
* :func:`points_to_cloud2` / :func:`cloud2_to_points`: ``sensor_msgs/PointCloud2``
  with float32 ``x y z`` (metres) and packed float32 ``rgb`` <-> arrays;
  :func:`records_to_cloud2`: the same message from ready ``x y z rgb`` rows.
* :func:`rectified_camera_info`: ``sensor_msgs/CameraInfo`` of a rectified image
  in ROS conventions.
* :func:`stamp_to_ns` / :func:`ns_to_stamp`: ``builtin_interfaces/Time`` <-> int ns.

Large byte fields are filled with one copy of the array's memory into the
``array.array('B')`` rclpy keeps for a ``uint8[]`` field (:func:`message_bytes`; ``bytes``
would be copied twice, once by ``tobytes`` and again by rclpy) and read back with
``np.frombuffer`` (no copy: arrays returned by the readers are views into the message).
"""
from __future__ import annotations

import array
from dataclasses import dataclass

import cv2
import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField, RegionOfInterest
from std_msgs.msg import Header
from stereo_msgs.msg import DisparityImage

from canopy_stereo.disparity.wire import from_wire, to_wire
from canopy_stereo.errors import ImageError
from canopy_stereo.geometry.clouds import check_cloud

#: encoding -> (numpy dtype, channels)
ENCODINGS: dict[str, tuple[str, int]] = {
    "mono8": ("u1", 1), "8UC1": ("u1", 1), "8SC1": ("i1", 1),
    "bgr8": ("u1", 3), "rgb8": ("u1", 3), "8UC3": ("u1", 3),
    "bgra8": ("u1", 4), "rgba8": ("u1", 4), "8UC4": ("u1", 4),
    "mono16": ("u2", 1), "16UC1": ("u2", 1), "16SC1": ("i2", 1),
    "bgr16": ("u2", 3), "rgb16": ("u2", 3), "16UC3": ("u2", 3),
    "32SC1": ("i4", 1), "32FC1": ("f4", 1), "32FC3": ("f4", 3), "64FC1": ("f8", 1),
}

#: 8-bit encodings that :func:`msg_to_bgr` / :func:`msg_to_mono` convert.
COLOUR_ENCODINGS = ("bgr8", "rgb8", "bgra8", "rgba8", "mono8", "8UC1", "8UC3")

_NS = 1_000_000_000


def message_bytes(data: np.ndarray) -> array.array:
    """The bytes of ``data`` (any dtype; made C-contiguous if it is not) as the
    ``array.array('B')`` rclpy stores in a ``uint8[]`` message field: one copy."""
    out = array.array("B")
    out.frombytes(np.ascontiguousarray(data).reshape(-1).view(np.uint8))
    return out


def stamp_to_ns(stamp: Time) -> int:
    """``builtin_interfaces/Time`` -> integer nanoseconds."""
    return int(stamp.sec) * _NS + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds (>= 0) -> ``builtin_interfaces/Time``."""
    ns = int(ns)
    return Time(sec=ns // _NS, nanosec=ns % _NS)


def make_header(stamp_ns: int, frame_id: str = "") -> Header:
    """``std_msgs/Header`` with the stamp in nanoseconds."""
    return Header(stamp=ns_to_stamp(stamp_ns), frame_id=frame_id)


def _default_encoding(image: np.ndarray) -> str:
    channels = 1 if image.ndim == 2 else image.shape[2]
    table = {("u1", 1): "mono8", ("u1", 3): "bgr8", ("u1", 4): "bgra8", ("u2", 1): "mono16",
             ("u2", 3): "bgr16", ("i2", 1): "16SC1", ("i4", 1): "32SC1", ("f4", 1): "32FC1",
             ("f4", 3): "32FC3", ("f8", 1): "64FC1", ("i1", 1): "8SC1"}
    key = (image.dtype.str[1:], channels)
    if key not in table:
        raise ImageError(f"no image encoding for dtype {image.dtype} with {channels} channel(s)")
    return table[key]


def image_to_msg(image: np.ndarray, encoding: str | None = None, *, stamp_ns: int = 0,
                 frame_id: str = "") -> Image:
    """``sensor_msgs/Image`` holding ``image`` (copied, little-endian, no row padding).

    Args:
        image: (H, W) or (H, W, C) array.
        encoding: ROS encoding (``"bgr8"``, ``"mono8"``, ``"32FC1"``, ...); by default
            chosen from the dtype and channels (uint8 3-channel -> ``bgr8``).
        stamp_ns: header stamp in nanoseconds.
        frame_id: header frame.
    """
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim not in (2, 3):
        raise ImageError(f"an image must be (H, W) or (H, W, C), got shape {image.shape}")
    encoding = encoding or _default_encoding(image)
    if encoding not in ENCODINGS:
        raise ImageError(f"unsupported image encoding {encoding!r}")
    dtype, channels = ENCODINGS[encoding]
    got_channels = 1 if image.ndim == 2 else image.shape[2]
    if got_channels != channels or image.dtype.str[1:] != dtype:
        raise ImageError(f"encoding {encoding} needs {channels} channel(s) of {np.dtype(dtype)}, "
                         f"got {got_channels} of {image.dtype}")
    data = np.ascontiguousarray(image, dtype=np.dtype(dtype).newbyteorder("<"))
    h, w = image.shape[:2]
    msg = Image(header=make_header(stamp_ns, frame_id), height=h, width=w, encoding=encoding,
                is_bigendian=0, step=w * channels * data.itemsize, check_fields=True)
    # assigned, not passed to the constructor: rclpy's generated __init__ copies a uint8[]
    # field element by element (0.7 ms for a 640x480 bgr8 image); with check_fields the setter
    # keeps the array.array as it is (without, it copies it once more)
    msg.data = message_bytes(data)
    return msg


def msg_to_image(msg: Image, encodings=None, *, expected_size=None) -> np.ndarray:
    """Array view of a ``sensor_msgs/Image``: (H, W) for one channel, else (H, W, C).

    Args:
        msg: the message.
        encodings: accepted encodings (None: any in :data:`ENCODINGS`).
        expected_size: ``(width, height)`` the image must have, or None.

    Raises :class:`ImageError` naming the problem: unknown or unaccepted encoding,
    size mismatch, or a data buffer shorter than ``step * height``.
    """
    enc = msg.encoding
    if enc not in ENCODINGS:
        raise ImageError(f"unsupported image encoding {enc!r}")
    if encodings is not None and enc not in encodings:
        raise ImageError(f"image encoding {enc!r} not accepted here; expected one of "
                         f"{', '.join(encodings)}")
    dtype, channels = ENCODINGS[enc]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    if h == 0 or w == 0:
        raise ImageError(f"empty image ({w}x{h})")
    if expected_size is not None and (w, h) != tuple(expected_size):
        raise ImageError(f"image is {w}x{h} but {expected_size[0]}x{expected_size[1]} is expected")
    row_bytes = w * channels * dt.itemsize
    if step < row_bytes:
        raise ImageError(f"image step {step} is smaller than a row ({row_bytes} bytes)")
    buf = np.frombuffer(msg.data, dtype=np.uint8)
    if buf.size < step * h:
        raise ImageError(f"image data has {buf.size} bytes, {step * h} expected for {w}x{h} {enc}")
    rows = buf[: step * h].reshape(h, step)[:, :row_bytes]
    arr = np.ascontiguousarray(rows).view(dt).reshape((h, w) if channels == 1 else (h, w, channels))
    if dt.byteorder == ">":
        arr = arr.astype(dt.newbyteorder("="))
    return arr


def msg_to_bgr(msg: Image, expected_size=None) -> np.ndarray:
    """uint8 BGR (H, W, 3) from an 8-bit colour or mono image message."""
    img = msg_to_image(msg, COLOUR_ENCODINGS, expected_size=expected_size)
    enc = msg.encoding
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if enc == "rgb8":
        return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    if enc == "rgba8":
        return cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def msg_to_mono(msg: Image, expected_size=None) -> np.ndarray:
    """uint8 grey (H, W) from an 8-bit colour or mono image message."""
    img = msg_to_image(msg, COLOUR_ENCODINGS, expected_size=expected_size)
    enc = msg.encoding
    if img.ndim == 2:
        return img
    code = {"rgb8": cv2.COLOR_RGB2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY,
            "bgra8": cv2.COLOR_BGRA2GRAY}.get(enc, cv2.COLOR_BGR2GRAY)
    if img.shape[2] == 4 and enc not in ("rgba8", "bgra8"):
        code = cv2.COLOR_BGRA2GRAY
    return cv2.cvtColor(img, code)


# --------------------------------------------------------------------------- disparity


@dataclass(frozen=True)
class DisparityFrame:
    """Contents of a ``stereo_msgs/DisparityImage`` (ROS convention: ``Z = f t / d``).

    Attributes:
        disparity: float32 (H, W) pixels, NaN where invalid. Values are those of
            the message: already reduced by ``cx_left - cx_right`` of the rectified
            cameras, so add that offset back to get ``u_left - u_right``.
        f: rectified focal length (pixels).
        t: baseline (metres).
        min_disparity, max_disparity: search range (message convention, pixels).
        delta_d: smallest disparity step the matcher resolves (pixels).
        valid_window: ``(x_offset, y_offset, width, height)`` of the valid region.
        stamp_ns, frame_id: header.
    """

    disparity: np.ndarray
    f: float
    t: float
    min_disparity: float
    max_disparity: float
    delta_d: float
    valid_window: tuple[int, int, int, int]
    stamp_ns: int = 0
    frame_id: str = ""

    def depth(self) -> np.ndarray:
        """Depth ``Z = f t / d`` in metres (float32 (H, W), NaN where invalid or d <= 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.float32(self.f * self.t) / self.disparity
        z[~(self.disparity > 0)] = np.nan
        return z


def valid_window(disp: np.ndarray, min_disparity: float = 0.0) -> tuple[int, int, int, int]:
    """Bounding box ``(x, y, w, h)`` of pixels with ``disp >= min_disparity`` (zeros if none)."""
    return _mask_window(np.isfinite(disp) & (disp >= min_disparity))


def _mask_window(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box ``(x, y, w, h)`` of the true pixels of a boolean (H, W) mask (zeros if none)."""
    cols, rows = np.flatnonzero(mask.any(axis=0)), np.flatnonzero(mask.any(axis=1))
    if cols.size == 0:
        return 0, 0, 0, 0
    return int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)


def disparity_to_msg(disp: np.ndarray, f: float, t: float, min_disparity: float,
                     max_disparity: float, *, delta_d: float = 1.0 / 16.0, stamp_ns: int = 0,
                     frame_id: str = "", doffs: float = 0.0) -> DisparityImage:
    """``stereo_msgs/DisparityImage`` from a rectified disparity map of the core.

    Args:
        disp: float (H, W) ``u_left - u_right`` in rectified pixels; negative or
            non-finite = invalid (the core's convention).
        f: rectified focal length (pixels); t: baseline (metres).
        min_disparity, max_disparity: the search range, in the same pixels as ``disp``.
        delta_d: the matcher's disparity resolution (pixels).
        doffs: ``cx_left - cx_right`` of the rectified cameras. As the message
            definition requires, it is subtracted from the disparities and the
            range, so that consumers get depth as ``Z = f t / d``.

    Invalid pixels (and values outside the range) are written as
    ``min_disparity - 1`` (after the shift): below the range, as ROS expects.
    ``valid_window`` is the bounding box of the valid pixels. ``f``, ``t``, the range and
    ``delta_d`` are float32 on the wire and are stored rounded to float32 here, so that a
    node of the same process handed this object (intra-process) reads what a subscriber
    in another process reads.
    """
    d = np.asarray(disp, np.float32)
    if d.ndim != 2:
        raise ImageError(f"a disparity map must be (H, W), got shape {d.shape}")
    lo, hi = float(min_disparity) - float(doffs), float(max_disparity) - float(doffs)
    rows, cols = d.shape
    # the wire values are written straight into the message's (little-endian) data buffer
    data = _zeroed_bytes(rows * cols * 4) if np.little_endian else None
    wire = None if data is None else np.frombuffer(data, np.float32).reshape(rows, cols)
    # valid: finite, >= 0 and inside the range (NaN compares false; +inf is above the range)
    out, (x, y, w, h) = to_wire(d, valid_min=max(0.0, float(min_disparity)), valid_max=float(max_disparity),
                                doffs=float(doffs), fill=lo - 1.0, out=wire)
    msg = DisparityImage()
    msg.header = make_header(stamp_ns, frame_id)
    if data is None:
        msg.image = image_to_msg(out, "32FC1", stamp_ns=stamp_ns, frame_id=frame_id)
    else:
        msg.image = Image(header=make_header(stamp_ns, frame_id), height=rows, width=cols, encoding="32FC1",
                          is_bigendian=0, step=cols * 4)
        msg.image.data = data
    msg.f = _wire_float32(f)
    msg.t = _wire_float32(t)
    msg.valid_window = RegionOfInterest(x_offset=x, y_offset=y, width=w, height=h,
                                        do_rectify=False)
    msg.min_disparity = _wire_float32(lo)
    msg.max_disparity = _wire_float32(hi)
    msg.delta_d = _wire_float32(delta_d)
    return msg


def _zeroed_bytes(n: int) -> array.array:
    """A zeroed ``array.array('B')`` of ``n`` bytes (for a message's ``uint8[]`` field, written
    in place through a numpy view): one fill instead of a temporary array and a copy."""
    return _ZERO_BYTE * int(n)


_ZERO_BYTE = array.array("B", [0])


def _wire_float32(value: float) -> float:
    """``value`` as a ``float32`` message field carries it (rounded to float32)."""
    return float(np.float32(value))


def msg_to_disparity(msg: DisparityImage) -> DisparityFrame:
    """Read a ``DisparityImage``: float32 disparity (message convention), NaN where invalid
    (below ``min_disparity``, above ``max_disparity`` or non-finite)."""
    img = msg_to_image(msg.image, ("32FC1",))
    lo, hi = float(msg.min_disparity), float(msg.max_disparity)
    d = from_wire(img, min_disparity=lo, max_disparity=hi)
    roi = msg.valid_window
    return DisparityFrame(
        disparity=d, f=float(msg.f), t=float(msg.t), min_disparity=lo, max_disparity=hi,
        delta_d=float(msg.delta_d),
        valid_window=(int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height)),
        stamp_ns=stamp_to_ns(msg.header.stamp), frame_id=msg.header.frame_id)


# --------------------------------------------------------------------------- point clouds

_XYZRGB_FIELDS = [("x", 0), ("y", 4), ("z", 8), ("rgb", 12)]
_PF_DTYPES = {PointField.INT8: "i1", PointField.UINT8: "u1", PointField.INT16: "i2",
              PointField.UINT16: "u2", PointField.INT32: "i4", PointField.UINT32: "u4",
              PointField.FLOAT32: "f4", PointField.FLOAT64: "f8"}


def pack_rgb(colors: np.ndarray) -> np.ndarray:
    """uint8 RGB (..., 3) -> float32 (...) holding ``0x00RRGGBB`` bits (PCL's ``rgb``)."""
    c = np.asarray(colors, np.uint8)
    packed = (c[..., 0].astype(np.uint32) << 16) | (c[..., 1].astype(np.uint32) << 8) | c[..., 2]
    return packed.view(np.float32)


def pack_bgr_image(bgr: np.ndarray) -> np.ndarray:
    """uint8 BGR image (H, W, 3) -> float32 (H, W) packed ``rgb`` (as :func:`pack_rgb` of
    its RGB), in one OpenCV pass: the byte order B, G, R, 0 is little-endian ``0x00RRGGBB``."""
    import cv2

    bgr = np.ascontiguousarray(bgr, np.uint8)
    if bgr.ndim != 3 or bgr.shape[2] != 3:
        raise ImageError(f"a BGR image must be (H, W, 3), got shape {bgr.shape}")
    bgrx = cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA)
    bgrx[..., 3] = 0
    return bgrx.view("<u4")[..., 0].view(np.float32)


def unpack_rgb(rgb: np.ndarray) -> np.ndarray:
    """float32 ``rgb`` field (...) -> uint8 RGB (..., 3)."""
    bits = np.ascontiguousarray(rgb, np.float32).view(np.uint32)
    return np.stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255], axis=-1).astype(np.uint8)


def points_to_cloud2(points: np.ndarray, colors: np.ndarray | None = None, *, stamp_ns: int = 0,
                     frame_id: str = "canopy_world", organized: bool | None = None,
                     rgb: np.ndarray | None = None) -> PointCloud2:
    """``sensor_msgs/PointCloud2`` (float32 x, y, z [, packed rgb]) from points in metres.

    Args:
        points: (N, 3) or organized (H, W, 3) coordinates in metres; NaN rows
            mark missing points.
        colors: optional uint8 RGB with the same leading shape.
        organized: keep the (H, W) layout with NaN points (``is_dense = False``);
            default: True for (H, W, 3) input. When False, NaN points are removed
            and the cloud is one row with ``is_dense = True``.
        rgb: instead of ``colors``, the already packed float32 ``rgb`` values
            (:func:`pack_rgb`, :func:`pack_bgr_image`) with the points' leading shape.
    """
    pts = check_cloud(points, organized=None, name="points", dtype=np.float32, error=ImageError)
    if colors is not None and rgb is not None:
        raise ImageError("give colours or packed rgb, not both")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != pts.shape:
            raise ImageError(f"colours {colors.shape} do not match points {pts.shape}")
        rgb = pack_rgb(colors)
    elif rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape != pts.shape[:-1] or rgb.dtype != np.float32:
            raise ImageError(f"packed rgb must be float32 {pts.shape[:-1]}, got {rgb.dtype} {rgb.shape}")
    if organized is None:
        organized = pts.ndim == 3
    flat = pts.reshape(-1, 3)
    fields = _XYZRGB_FIELDS if rgb is not None else _XYZRGB_FIELDS[:3]
    rec = np.empty((len(flat), len(fields)), np.float32)
    rec[:, :3] = flat
    if rgb is not None:
        rec[:, 3] = rgb.reshape(-1)
    # a sum is NaN/inf when any term is (and only overflows for |x| > 1e38 m): one pass,
    # where isfinite(...).all(axis=1) over the strided columns takes ten times longer
    finite = np.isfinite(rec[:, 0] + rec[:, 1] + rec[:, 2])
    all_finite = bool(finite.all())
    if organized:
        height, width = (pts.shape[0], pts.shape[1]) if pts.ndim == 3 else (1, len(flat))
        dense = all_finite
    else:
        if not all_finite:
            rec = rec[finite]
        height, width, dense = 1, len(rec), True
    return _cloud_message(rec, fields, height, width, dense, stamp_ns, frame_id)


def _cloud_message(rec: np.ndarray, fields, height: int, width: int, dense: bool, stamp_ns: int,
                   frame_id: str) -> PointCloud2:
    point_step = 4 * len(fields)
    msg = PointCloud2()
    msg.header = make_header(stamp_ns, frame_id)
    msg.height, msg.width = int(height), int(width)
    msg.fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
                  for n, o in fields]
    msg.is_bigendian = False
    msg.point_step = point_step
    msg.row_step = point_step * int(width)
    msg.data = message_bytes(rec)
    msg.is_dense = dense
    return msg


def records_to_cloud2(records: np.ndarray, stamp_ns: int = 0, *, frame_id: str = "canopy_world",
                      organized_shape: tuple[int, int] | None = None) -> PointCloud2:
    """``PointCloud2`` from rows of float32 ``x, y, z, rgb`` as
    :func:`~canopy_stereo.geometry.frames.reproject_disparity_records` writes them: the same
    message as :func:`points_to_cloud2` with ``rgb``, with one copy of the rows.

    Args:
        records: float32 (N, 4); for an unorganized cloud every row must be a point (the
            cloud is dense), for an organized one rows without a point have NaN coordinates.
        organized_shape: ``(H, W)`` with ``H * W = N`` for an organized cloud (``is_dense``
            when every point is finite), None for a dense one-row cloud.
    """
    rec = np.asarray(records)
    if rec.ndim != 2 or rec.shape[1] != 4 or rec.dtype != np.float32:
        raise ImageError(f"records must be float32 (N, 4) x, y, z, rgb; got {rec.dtype} {rec.shape}")
    if organized_shape is None:
        return _cloud_message(rec, _XYZRGB_FIELDS, 1, len(rec), True, stamp_ns, frame_id)
    h, w = (int(v) for v in organized_shape)
    if h * w != len(rec):
        raise ImageError(f"an organized {w}x{h} cloud needs {h * w} records, got {len(rec)}")
    dense = bool(np.isfinite(rec[:, 0] + rec[:, 1] + rec[:, 2]).all())
    return _cloud_message(rec, _XYZRGB_FIELDS, h, w, dense, stamp_ns, frame_id)


def cloud2_to_points(msg: PointCloud2, organized: bool = False):
    """Points (metres) and colours of a ``PointCloud2`` with x, y, z fields.

    Returns ``(points, colors)``: float32 (N, 3) (or (H, W, 3) with ``organized``)
    and uint8 RGB of the same leading shape, or None without an ``rgb``/``rgba``
    field. Any field layout, row padding and byte order are handled.
    """
    layout = {f.name: f for f in msg.fields}
    missing = [n for n in "xyz" if n not in layout]
    if missing:
        raise ImageError(f"PointCloud2 has no {', '.join(missing)} field(s)")
    endian = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for name in ("x", "y", "z", "rgb", "rgba"):
        if name in layout:
            f = layout[name]
            if f.datatype not in _PF_DTYPES:
                raise ImageError(f"PointCloud2 field {name!r} has unknown datatype {f.datatype}")
            names.append(name)
            formats.append(endian + _PF_DTYPES[f.datatype])
            offsets.append(int(f.offset))
    h, w, step, row_step = int(msg.height), int(msg.width), int(msg.point_step), int(msg.row_step)
    if step <= 0 or row_step < step * w:
        raise ImageError(f"PointCloud2 has point_step {step} and row_step {row_step} for width {w}")
    dt = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": step})
    buf = np.frombuffer(msg.data, np.uint8)
    if buf.size < row_step * h:
        raise ImageError(f"PointCloud2 data has {buf.size} bytes, {row_step * h} expected")
    rows = np.ascontiguousarray(buf[: row_step * h].reshape(h, row_step)[:, : step * w])
    rec = rows.view(dt).reshape(h, w)
    pts = np.stack([rec["x"], rec["y"], rec["z"]], axis=-1).astype(np.float32)
    colors = None
    colour_field = "rgb" if "rgb" in names else ("rgba" if "rgba" in names else None)
    if colour_field is not None:
        colors = unpack_rgb(rec[colour_field].astype(np.float32))
    if not organized:
        pts = pts.reshape(-1, 3)
        colors = None if colors is None else colors.reshape(-1, 3)
    return pts, colors


# --------------------------------------------------------------------------- camera info


def rectified_camera_info(K_rect: np.ndarray, size, baseline_m: float, side: str,
                          *, stamp_ns: int = 0, frame_id: str = "") -> CameraInfo:
    """``sensor_msgs/CameraInfo`` of one rectified image, in ROS conventions.

    The image is already rectified, so ``D`` is zero and ``R`` the identity;
    ``K`` is the rectified intrinsic matrix and ``P = [K | (Tx, 0, 0)]`` with
    ``Tx = 0`` for the left camera and ``Tx = -fx * baseline`` (metres) for the
    right one, as ``stereo_image_proc`` and ``image_geometry`` expect (depth
    ``Z = fx * baseline / (d - (cx_left - cx_right))``).

    Args:
        K_rect: (3, 3) intrinsics of the rectified camera (pixels).
        size: ``(width, height)`` of the rectified image.
        baseline_m: distance between the camera centres in metres.
        side: ``"left"`` or ``"right"``.
    """
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    K = np.asarray(K_rect, np.float64)
    P = np.hstack([K, np.zeros((3, 1))])
    if side == "right":
        P[0, 3] = -K[0, 0] * float(baseline_m)
    info = CameraInfo()
    info.header = make_header(stamp_ns, frame_id)
    info.width, info.height = int(size[0]), int(size[1])
    info.distortion_model = "plumb_bob"
    info.d = [0.0] * 5
    info.k = [float(v) for v in K.ravel()]
    info.r = [float(v) for v in np.eye(3).ravel()]
    info.p = [float(v) for v in P.ravel()]
    info.binning_x = info.binning_y = 0
    info.roi = RegionOfInterest(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
    return info


def camera_info_msg(calibration, stamp_ns: int = 0, *, frame_id: str = "") -> CameraInfo:
    """``sensor_msgs/CameraInfo`` of a raw camera from a
    :class:`~canopy_stereo.geometry.frames.CameraCalibration` (REP 104: ``K``, ``D`` of the
    raw image, ``R`` to the rectified camera, ``P`` of the rectified camera)."""
    c = calibration
    info = CameraInfo()
    info.header = make_header(stamp_ns, frame_id)
    info.width, info.height = int(c.width), int(c.height)
    info.distortion_model = c.distortion_model
    info.d = [float(v) for v in np.asarray(c.D, np.float64).ravel()]
    info.k = [float(v) for v in np.asarray(c.K, np.float64).ravel()]
    info.r = [float(v) for v in np.asarray(c.R, np.float64).ravel()]
    info.p = [float(v) for v in np.asarray(c.P, np.float64).ravel()]
    info.binning_x = info.binning_y = 0
    info.roi = RegionOfInterest(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
    return info


def uncalibrated_camera_info(size, stamp_ns: int = 0, *, frame_id: str = "") -> CameraInfo:
    """``CameraInfo`` of an image without a metric camera (a projective, Hartley,
    rectification): size only, ``D``, ``K``, ``R``, ``P`` zero, as the message
    definition prescribes for an uncalibrated camera."""
    info = CameraInfo()
    info.header = make_header(stamp_ns, frame_id)
    info.width, info.height = int(size[0]), int(size[1])
    info.distortion_model = ""
    info.roi = RegionOfInterest(x_offset=0, y_offset=0, width=0, height=0, do_rectify=False)
    return info


def camera_info_matrices(info: CameraInfo) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(K (3, 3), D (n,), R (3, 3), P (3, 4))`` of a ``CameraInfo`` (float64)."""
    return (np.asarray(info.k, np.float64).reshape(3, 3), np.asarray(info.d, np.float64),
            np.asarray(info.r, np.float64).reshape(3, 3), np.asarray(info.p, np.float64).reshape(3, 4))


def is_calibrated(info: CameraInfo) -> bool:
    """True when the ``CameraInfo`` has a projection (``P[0, 0] > 0``)."""
    return float(info.p[0]) > 0.0


def depth_to_msg(depth_m: np.ndarray, stamp_ns: int = 0, *, frame_id: str = "") -> Image:
    """REP 118 depth image: 32FC1, metres along the optical axis, NaN where unknown."""
    d = np.asarray(depth_m, np.float32)
    if d.ndim != 2:
        raise ImageError(f"a depth image must be (H, W), got shape {d.shape}")
    return image_to_msg(d, "32FC1", stamp_ns=stamp_ns, frame_id=frame_id)
