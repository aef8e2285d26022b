"""Point clouds as arrays: the one check of (N, 3) point lists and (H, W, 3) organized clouds.

An *organized* cloud is an (H, W, 3) array of world points on the pixel grid of
the (left) image that saw them, NaN where a pixel has no point
(:mod:`~canopy_stereo.geometry.triangulation` makes them, :mod:`canopy_stereo.measure`
measures them); a point list is (N, 3). Both are in world units (the rig's) or,
in ROS messages, metres. Every reader, writer and consumer of clouds checks its
input here, so they all accept and refuse the same arrays with the same words.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError


def check_cloud(points, *, organized: bool | None = True, name: str = "organized cloud", dtype=np.float64,
                min_size: int = 1, error: type[CanopyStereoError] = CanopyStereoError) -> np.ndarray:
    """``points`` as a ``dtype`` array of 3-D points, or ``error`` naming the problem.

    Args:
        points: array-like of real numbers (int, uint or float; NaN marks a missing point).
        organized: True: (H, W, 3) with H, W >= ``min_size``; False: (N, 3); None: either.
        name: what the array is, for the message (``"organized cloud"``, ``"points"``, a file).
        dtype: dtype of the returned array (float64, or float32 for messages).
        min_size: smallest H and W of an organized cloud.
        error: the :class:`~canopy_stereo.errors.CanopyStereoError` subclass raised.

    Raises ``error`` for non-numeric or complex input and for a wrong shape; the values
    themselves (NaN, inf) are the caller's business.
    """
    try:
        raw = np.asarray(points)
    except (TypeError, ValueError):
        raise error(f"{name} is not numeric") from None
    if raw.dtype.kind not in "fiu":
        if raw.dtype.kind == "O":
            try:
                raw = np.asarray(points, dtype=np.float64)
            except (TypeError, ValueError):
                raise error(f"{name} is not numeric") from None
        elif raw.dtype.kind == "c":
            raise error(f"{name} must hold real coordinates (float), got dtype {raw.dtype}")
        else:
            raise error(f"{name} is not numeric (dtype {raw.dtype})")
    shape = raw.shape
    if organized is True:
        if raw.ndim != 3 or shape[2] != 3 or shape[0] < min_size or shape[1] < min_size:
            raise error(f"{name} must be an (H, W, 3) array (x, y, z per pixel: shape (H, W, 3)), got shape {shape}")
    elif organized is False:
        if raw.ndim != 2 or shape[1] != 3:
            raise error(f"{name} must be an (N, 3) array (x, y, z per point), got shape {shape}")
    elif raw.ndim not in (2, 3) or shape[-1] != 3:
        raise error(f"{name} must be an (N, 3) or (H, W, 3) array, got shape {shape}")
    return np.asarray(raw, dtype=dtype)


def check_on_grid(image, organized, name: str, *, hint: str = "") -> None:
    """Raise :class:`CanopyStereoError` unless the (H, W[, C]) ``image`` (a mask, leaf ids)
    lies on the pixel grid of the (H, W, 3) ``organized`` cloud; ``hint`` is added to the message."""
    h, w = np.shape(image)[:2]
    H, W = np.shape(organized)[:2]
    if (h, w) != (H, W):
        raise CanopyStereoError(f"{name} is {w}x{h} but the organized cloud is {W}x{H}"
                                + (f" ({hint})" if hint else ""))
