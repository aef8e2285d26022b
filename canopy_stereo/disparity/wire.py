"""A disparity map to and from the ``stereo_msgs/DisparityImage`` convention, one pass each.

The message stores ``d - doffs`` (``doffs = cx_left - cx_right`` of the rectified cameras,
so that ``Z = f t / d`` holds on the wire), marks invalid pixels with a value below
``min_disparity`` and carries the valid pixels' bounding box as ``valid_window``. The ROS
conversions (:func:`canopy_stereo.ros.convert.disparity_to_msg` and
:func:`~canopy_stereo.ros.convert.msg_to_disparity`) call these on every frame of the graph:
each is a single pass over the (H, W) float32 map (0.1-0.2 ms at 640x480 instead of 0.7-1 ms
for the chain of numpy masks, copies and reductions it replaces, with the same values).
"""
from __future__ import annotations

import numpy as np
from numba import njit


def to_wire(disp: np.ndarray, *, valid_min: float, valid_max: float, doffs: float,
            fill: float, out: np.ndarray | None = None) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """``(wire, (x, y, w, h))``: the message values of a disparity map and the bounding box
    of its valid pixels.

    Args:
        disp: float32 (H, W) ``u_left - u_right`` (rectified pixels); NaN = invalid.
        valid_min, valid_max: a pixel is valid when ``valid_min <= d <= valid_max``
            (NaN never is; +inf is above any range).
        doffs: subtracted from the valid values (float32 arithmetic); 0 leaves them bit for bit.
        fill: the value written for invalid pixels.
        out: float32 (H, W) array the values are written into (e.g. a view of a message's
            buffer); default a new one.

    Returns float32 (H, W) ``d - doffs`` where valid, ``fill`` elsewhere, and the valid
    pixels' box ``(x, y, width, height)`` (zeros when none is valid).
    """
    d = np.ascontiguousarray(disp, dtype=np.float32)
    if d.ndim != 2:
        raise ValueError(f"a disparity map must be (H, W), got shape {d.shape}")
    if out is None:
        out = np.empty_like(d)
    elif out.shape != d.shape or out.dtype != np.float32:
        raise ValueError(f"out must be float32 {d.shape}, got {out.dtype} {out.shape}")
    x0, y0, x1, y1 = _to_wire(d, np.float32(valid_min), np.float32(valid_max), np.float32(doffs),
                              np.float32(fill), out)
    if x1 < x0:
        return out, (0, 0, 0, 0)
    return out, (int(x0), int(y0), int(x1 - x0 + 1), int(y1 - y0 + 1))


def from_wire(wire: np.ndarray, *, min_disparity: float, max_disparity: float) -> np.ndarray:
    """float32 (H, W) copy of a message's disparity values with NaN where a pixel is not
    finite or outside ``[min_disparity, max_disparity]`` (the message's own range)."""
    w = np.ascontiguousarray(wire, dtype=np.float32)
    if w.ndim != 2:
        raise ValueError(f"a disparity map must be (H, W), got shape {w.shape}")
    out = np.empty_like(w)
    _from_wire(w, np.float32(min_disparity), np.float32(max_disparity), out)
    return out


def count_nonfinite(values: np.ndarray) -> int:
    """Number of NaN or infinite values of a float32 (H, W) map (any strides, e.g. the rows of a
    message's payload without their padding), in one pass that allocates nothing."""
    v = np.asarray(values)
    if v.ndim != 2 or v.dtype != np.float32 or not v.dtype.isnative:
        return int(v.size - np.count_nonzero(np.isfinite(v)))
    return int(_count_nonfinite(v))


@njit(cache=True, nogil=True)
def _count_nonfinite(v):  # pragma: no cover - numba
    h, w = v.shape
    n = 0
    for i in range(h):
        for j in range(w):
            x = v[i, j]
            n += not (x - x == 0)  # NaN - NaN and inf - inf are NaN: not equal to 0
    return n


@njit(cache=True, nogil=True, error_model="numpy")
def _to_wire(d, lo, hi, doffs, fill, out):  # pragma: no cover - numba
    # branch-free per pixel (selects and min/max reductions the compiler vectorises)
    h, w = d.shape
    x0, y0, x1, y1 = w, h, -1, -1
    for i in range(h):
        first, last = w, -1
        for j in range(w):
            v = d[i, j]
            ok = (v >= lo) & (v <= hi)
            out[i, j] = (v - doffs) if ok else fill
            first = min(first, j if ok else w)
            last = max(last, j if ok else -1)
        if last >= 0:
            x0 = min(x0, first)
            x1 = max(x1, last)
            y0 = min(y0, i)
            y1 = i
    return x0, y0, x1, y1


@njit(cache=True, nogil=True)
def _from_wire(w, lo, hi, out):  # pragma: no cover - numba
    h, wd = w.shape
    nan = np.float32(np.nan)
    for i in range(h):
        for j in range(wd):
            v = w[i, j]
            out[i, j] = v if (v >= lo and v <= hi) else nan  # NaN and +-inf fail (finite range)
