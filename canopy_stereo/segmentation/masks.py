"""Reading and writing plant masks and leaf-id images.

* A plant mask is a single-channel image, nonzero = plant (written as 0/255 PNG).
* A leaf-id image holds one integer id per leaf, 0 = not a leaf: 8- or 16-bit
  grey PNG (read without scaling), or a colour PNG where every distinct colour
  is a leaf (id ``0xRRGGBB``) and black is background.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import ImageError


def _read_raw(path, what: str) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{what} not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ImageError(f"cannot read {what} {path}: not an image format OpenCV can decode")
    return img


def read_mask(path) -> np.ndarray:
    """(H, W) bool plant mask from an image file (nonzero = plant; colour: any channel)."""
    img = _read_raw(path, "mask")
    if img.ndim == 3:
        img = img[..., :3].max(axis=2)
    return img != 0


def read_leaf_ids(path) -> np.ndarray:
    """(H, W) int64 leaf ids from a grey (8/16-bit) or colour (id = 0xRRGGBB) image."""
    img = _read_raw(path, "leaf-id image")
    if img.ndim == 2:
        return img.astype(np.int64)
    if img.ndim == 3 and img.shape[2] >= 3:
        bgr = img[..., :3].astype(np.int64)
        if np.array_equal(bgr[..., 0], bgr[..., 1]) and np.array_equal(bgr[..., 1], bgr[..., 2]):
            return bgr[..., 0]
        return (bgr[..., 2] << 16) | (bgr[..., 1] << 8) | bgr[..., 0]
    raise ImageError(f"leaf-id image {path} has an unsupported shape {img.shape}")


def write_mask(path, mask: np.ndarray) -> Path:
    """Write a plant mask as an 8-bit 0/255 image (PNG recommended)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out = np.where(np.asarray(mask).astype(bool), 255, 0).astype(np.uint8)
    if not cv2.imwrite(str(path), out):
        raise ImageError(f"cannot write mask {path} (unknown extension or unwritable folder)")
    return path


def write_leaf_ids(path, ids: np.ndarray) -> Path:
    """Write leaf ids as an 8-bit (ids < 256) or 16-bit (ids < 65536) grey PNG."""
    path = Path(path)
    ids = np.asarray(ids)
    if ids.min(initial=0) < 0 or ids.max(initial=0) > 65535:
        raise ImageError("leaf ids must be in 0..65535 to be stored as an image")
    dtype = np.uint8 if ids.max(initial=0) < 256 else np.uint16
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), ids.astype(dtype)):
        raise ImageError(f"cannot write leaf-id image {path} (use .png)")
    return path


def parse_rect(text: str) -> tuple[int, int, int, int]:
    """``"x,y,w,h"`` -> 4 ints, or :class:`ImageError`."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [int(round(float(p))) for p in parts]
    except ValueError:
        raise ImageError(f"rectangle must be x,y,w,h (4 integers), got {text!r}") from None
    if len(vals) != 4:
        raise ImageError(f"rectangle must be x,y,w,h (4 integers), got {text!r}")
    return tuple(vals)  # type: ignore[return-value]
