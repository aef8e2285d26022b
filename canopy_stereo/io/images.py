"""Reading and checking images (OpenCV conventions: BGR, uint8, rows = v)."""
from __future__ import annotations

import glob
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import ImageError


def read_image(path, color: bool = True) -> np.ndarray:
    """Read an image file as uint8 BGR (H, W, 3) or grey (H, W).

    Raises :class:`ImageError` naming the file when it is missing or unreadable.
    16-bit images are scaled to 8 bits.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"image not found: {path}")
    flags = cv2.IMREAD_COLOR if color else cv2.IMREAD_GRAYSCALE
    img = cv2.imread(str(path), flags | cv2.IMREAD_ANYDEPTH)
    if img is None:
        raise ImageError(f"cannot read image {path}: not an image format OpenCV can decode")
    if img.dtype == np.uint16:
        img = (img // 257).astype(np.uint8)
    elif img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    return img


def expand_image_list(pattern_or_paths) -> list[Path]:
    """Paths from a glob pattern (sorted) or an explicit list (each entry a path or a glob)."""
    if isinstance(pattern_or_paths, (str, Path)):
        paths = sorted(Path(p) for p in glob.glob(str(pattern_or_paths)))
    else:
        paths = []
        for p in pattern_or_paths:
            matched = sorted(glob.glob(str(p)))
            paths += [Path(m) for m in matched] if matched else [Path(p)]
    return paths


class ImageFiles(Sequence):
    """Image files in order, read when indexed: a glob pattern (sorted) or a list of paths/globs.

    ``files[k]`` is the k-th image as :func:`read_image` returns it (grey (H, W) with
    ``color=False``), read from disk on each access, so a long calibration series never
    sits in memory at once; ``paths`` and ``names`` (file names, for messages) list the
    files. The calibrations of :mod:`canopy_stereo.geometry` take it wherever they take a
    list of images.

    Raises :class:`ImageError` when the pattern matches no file (``what`` names them).
    """

    def __init__(self, pattern_or_paths, *, color: bool = True, what: str = "images"):
        self.paths = expand_image_list(pattern_or_paths)
        self.color = bool(color)
        if not self.paths:
            raise ImageError(f"no {what} match {pattern_or_paths}")

    @property
    def names(self) -> list[str]:
        """File names (no folder), in order."""
        return [p.name for p in self.paths]

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return [read_image(p, color=self.color) for p in self.paths[index]]
        return read_image(self.paths[index], color=self.color)


def write_image(path, image: np.ndarray) -> Path:
    """Write ``image`` (uint8/uint16) to ``path``, creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise ImageError(f"cannot write image {path} (unknown extension or unwritable folder)")
    return path


def to_gray(image: np.ndarray, name: str = "image") -> np.ndarray:
    """uint8 grey (H, W) from uint8 grey or BGR/BGRA; other dtypes raise :class:`ImageError`."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ImageError(f"{name} must be uint8, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2GRAY)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    raise ImageError(f"{name} must be grey (H, W) or colour (H, W, 3), got shape {image.shape}")


def to_bgr(image: np.ndarray, name: str = "image") -> np.ndarray:
    """uint8 BGR (H, W, 3) from grey or BGR input."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ImageError(f"{name} must be uint8, got {image.dtype}")
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.ndim == 3 and image.shape[2] == 3:
        return image
    if image.ndim == 3 and image.shape[2] == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    raise ImageError(f"{name} must be grey (H, W) or colour (H, W, 3), got shape {image.shape}")


def check_pair(left: np.ndarray, right: np.ndarray, *, expected_size=None) -> None:
    """Raise :class:`ImageError` unless both images have the same (and expected) size.

    ``expected_size`` is ``(width, height)``, e.g. a rig's ``image_size``.
    """
    for name, img in (("left", left), ("right", right)):
        if img.ndim < 2 or img.shape[0] < 2 or img.shape[1] < 2:
            raise ImageError(f"{name} image is empty or too small: shape {img.shape}")
    if left.shape[:2] != right.shape[:2]:
        raise ImageError(
            f"image sizes differ: left {left.shape[1]}x{left.shape[0]}, "
            f"right {right.shape[1]}x{right.shape[0]}"
        )
    if expected_size is not None:
        w, h = expected_size
        if (left.shape[1], left.shape[0]) != (w, h):
            raise ImageError(
                f"images are {left.shape[1]}x{left.shape[0]} but the rig expects {w}x{h}"
            )
