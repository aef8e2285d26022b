"""Vegetation indices on normalised chromaticity, and Otsu thresholds.

With ``R, G, B`` the channels of a colour image, the chromatic coordinates
are ``r = R / (R + G + B)`` (likewise ``g``, ``b``), which removes most of the
effect of shading. Woebbecke's excess green ``ExG = 2g - r - b`` is high on
green vegetation and about 0 on grey; Meyer's excess red ``ExR = 1.4r - g`` is
high on soil, terracotta and red material; ``ExG - ExR`` (Meyer & Neto 2008)
separates plants from soil with a threshold near 0. Yellow and orange leaves
(croton) have ``ExG`` near or above 0 but ``ExG - ExR`` below 0, like soil.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import ImageError

#: Index names accepted by :func:`vegetation_index`.
INDICES = ("exg", "exgr", "exr")


def chromaticity(image_bgr: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalised ``(r, g, b)`` (each (H, W) float64 in [0, 1], summing to 1).

    Black pixels (``R + G + B = 0``) get 1/3 each.
    """
    img = np.asarray(image_bgr)
    if img.ndim != 3 or img.shape[2] < 3:
        raise ImageError(f"a colour (H, W, 3) BGR image is needed, got shape {img.shape}")
    bgr = img[..., :3].astype(np.float64)
    total = bgr.sum(axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        b, g, r = (np.where(total > 0, bgr[..., k] / total, 1.0 / 3.0) for k in range(3))
    return r, g, b


def excess_green(image_bgr: np.ndarray) -> np.ndarray:
    """``ExG = 2g - r - b`` (H, W) in [-1, 2]."""
    r, g, b = chromaticity(image_bgr)
    return 2.0 * g - r - b


def excess_red(image_bgr: np.ndarray) -> np.ndarray:
    """``ExR = 1.4r - g`` (H, W)."""
    r, g, _ = chromaticity(image_bgr)
    return 1.4 * r - g


def excess_green_minus_red(image_bgr: np.ndarray) -> np.ndarray:
    """``ExG - ExR = 3g - 2.4r - b`` (H, W): plants > 0 > soil."""
    r, g, b = chromaticity(image_bgr)
    return 3.0 * g - 2.4 * r - b


def vegetation_index(image_bgr: np.ndarray, name: str = "exg") -> np.ndarray:
    """The index ``name`` (``"exg"``, ``"exgr"`` = ExG - ExR, ``"exr"``) of a BGR image."""
    funcs = {"exg": excess_green, "exgr": excess_green_minus_red, "exr": excess_red}
    if name not in funcs:
        raise ImageError(f"unknown vegetation index {name!r}; choose one of {', '.join(INDICES)}")
    return funcs[name](image_bgr)


def otsu_threshold(values: np.ndarray, bins: int = 256, *, clip_percent: float = 0.5) -> float:
    """Otsu's threshold of real values (between-class variance maximised over ``bins`` levels).

    Non-finite values are ignored; values beyond the ``clip_percent`` and
    ``100 - clip_percent`` percentiles are clipped to them first, so a few
    wild values (a mismatched disparity) do not squeeze the histogram.
    Constant input returns that constant. When the classes are separated by an
    empty gap the threshold is the middle of the gap. Values strictly above
    the threshold form the upper class.
    """
    v = np.asarray(values, np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        raise ImageError("no finite values to threshold")
    if clip_percent > 0:
        v = np.clip(v, *np.percentile(v, [clip_percent, 100.0 - clip_percent]))
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return lo
    hist, edges = np.histogram(v, bins=bins, range=(lo, hi))
    centres = 0.5 * (edges[:-1] + edges[1:])
    p = hist.astype(np.float64) / hist.sum()
    w0 = np.cumsum(p)
    m = np.cumsum(p * centres)
    mt = m[-1]
    w1 = 1.0 - w0
    with np.errstate(invalid="ignore", divide="ignore"):
        between = (mt * w0 - m) ** 2 / (w0 * w1)
    between[~np.isfinite(between)] = -1.0
    # an empty gap between the classes gives a flat maximum: take its middle
    best = np.nonzero(between >= between.max() * (1.0 - 1e-12))[0]
    return float(0.5 * (edges[best[0] + 1] + edges[best[-1] + 1]))


def class_means(values: np.ndarray, threshold: float, *, clip_percent: float = 0.5) -> tuple[float, float]:
    """Means of the finite values at or below and above ``threshold`` (clipped as in
    :func:`otsu_threshold`)."""
    v = np.asarray(values, np.float64).ravel()
    v = v[np.isfinite(v)]
    if clip_percent > 0 and v.size:
        v = np.clip(v, *np.percentile(v, [clip_percent, 100.0 - clip_percent]))
    low, high = v[v <= threshold], v[v > threshold]
    return (float(low.mean()) if low.size else threshold, float(high.mean()) if high.size else threshold)
