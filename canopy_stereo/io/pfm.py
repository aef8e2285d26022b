"""Portable float maps (PFM), the Middlebury disparity format.

Rows are stored bottom-to-top; a negative scale means little-endian. Unknown
disparities are ``inf``.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from canopy_stereo.errors import ImageError


def read_pfm(path) -> np.ndarray:
    """Read a PFM file as float32 (H, W) or (H, W, 3), top row first."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ImageError(f"cannot read {path}: {exc.strerror or exc}") from None
    m = re.match(rb"(P[fF])\s+(\d+)\s+(\d+)\s+(-?[\d.eE+-]+)\s", data)
    if not m:
        raise ImageError(f"{path} is not a PFM file (expected a 'Pf' or 'PF' header)")
    channels = 3 if m.group(1) == b"PF" else 1
    w, h, scale = int(m.group(2)), int(m.group(3)), float(m.group(4))
    dtype = "<f4" if scale < 0 else ">f4"
    count = w * h * channels
    body = data[m.end():]
    if len(body) < 4 * count:
        raise ImageError(f"{path} is truncated: expected {count} floats for {w}x{h}")
    arr = np.frombuffer(body, dtype=dtype, count=count).astype(np.float32)
    arr = arr.reshape((h, w, channels) if channels == 3 else (h, w))
    return np.ascontiguousarray(arr[::-1])


def write_pfm(path, image: np.ndarray) -> Path:
    """Write float32 (H, W) or (H, W, 3) as little-endian PFM (top row first in memory)."""
    path = Path(path)
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        kind = b"Pf"
    elif image.ndim == 3 and image.shape[2] == 3:
        kind = b"PF"
    else:
        raise ImageError(f"PFM needs (H, W) or (H, W, 3) data, got shape {image.shape}")
    h, w = image.shape[:2]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(kind + b"\n%d %d\n-1\n" % (w, h))
        f.write(np.ascontiguousarray(image[::-1]).astype("<f4").tobytes())
    return path
