"""The package's one colour map for disparity and depth, and pictures that explain themselves.

Disparity and depth are drawn with OpenCV's *turbo* map, small values blue and
large values red (disparity: near = red; depth: far = red, as in the Rerun
viewer's depth images), invalid pixels black.
:func:`disparity_picture` and :func:`depth_picture` add a colour bar with tick
values, the unit and a title, so a PNG can be read without the code that made it.
"""
from __future__ import annotations

import cv2
import numpy as np

#: The colour map of every disparity/depth picture (and of the viewer's depth images).
COLORMAP = getattr(cv2, "COLORMAP_TURBO", cv2.COLORMAP_JET)
#: Its name, for viewers that colour depth themselves (Rerun's ``DepthImage(colormap=...)``).
COLORMAP_NAME = "turbo" if hasattr(cv2, "COLORMAP_TURBO") else "jet"

_FONT = cv2.FONT_HERSHEY_SIMPLEX


def colour_range(values: np.ndarray, *, lo: float | None = None, hi: float | None = None,
                 percentiles=(1.0, 99.0)) -> tuple[float, float]:
    """``(lo, hi)`` of the finite values: given bounds, else the 1st/99th percentiles."""
    v = np.asarray(values, np.float64)
    valid = np.isfinite(v)
    if lo is None or hi is None:
        if valid.any():
            plo, phi = np.percentile(v[valid], percentiles)
        else:
            plo, phi = 0.0, 1.0
        lo = float(plo) if lo is None else float(lo)
        hi = float(phi) if hi is None else float(hi)
    if not hi > lo:
        hi = lo + 1.0
    return float(lo), float(hi)


def colorize(values: np.ndarray, *, lo: float, hi: float, reverse: bool = False) -> np.ndarray:
    """uint8 BGR (H, W, 3) of a float (H, W) map: turbo from ``lo`` (blue) to ``hi`` (red)
    (``reverse``: ``lo`` red), values clipped to the range, NaN/inf black."""
    v = np.asarray(values, np.float64)
    valid = np.isfinite(v)
    t = np.zeros(v.shape, np.float64)
    t[valid] = np.clip((v[valid] - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    if reverse:
        t = 1.0 - t
    out = cv2.applyColorMap(np.rint(t * 255).astype(np.uint8), COLORMAP)
    out[~valid] = 0
    return out


def colorize_disparity(disp: np.ndarray, disp_max: float | None = None) -> np.ndarray:
    """uint8 BGR (H, W, 3) of a disparity map (pixels): turbo from 0 to ``disp_max``
    (default: the largest valid value), near (large disparity) red, invalid
    (negative, NaN, inf) black. No colour bar: see :func:`disparity_picture`."""
    d = np.asarray(disp, np.float32)
    valid = np.isfinite(d) & (d >= 0)
    top = float(disp_max) if disp_max else (float(d[valid].max()) if valid.any() else 1.0)
    return colorize(np.where(valid, d, np.nan), lo=0.0, hi=max(top, 1e-6))


def _ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """About ``n`` round tick values inside ``[lo, hi]``."""
    span = hi - lo
    raw = span / max(n - 1, 1)
    mag = 10.0 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=mag * 10)
    first = np.ceil(lo / step) * step
    return np.arange(first, hi + step * 1e-6, step)


def _fmt(v: float, step: float) -> str:
    decimals = max(0, int(-np.floor(np.log10(step))) if step > 0 else 0)
    return f"{v:.{min(decimals, 3)}f}"


def picture_offset(shape) -> tuple[int, int]:
    """``(row, column)`` where :func:`with_colour_bar` puts the top-left pixel of a picture
    of ``shape`` (the title strip is above it, the bar on its right)."""
    h = int(shape[0])
    scale = max(0.4, min(1.0, h / 600.0))
    return int(round(28 * scale)) + 6 + 4, 0


def with_colour_bar(picture: np.ndarray, *, lo: float, hi: float, unit: str, title: str = "",
                    reverse: bool = False, note: str = "") -> np.ndarray:
    """``picture`` (BGR) with a vertical colour bar on its right: tick values from
    ``lo`` to ``hi`` (the mapping of :func:`colorize` with the same ``reverse``),
    ``unit`` above the bar, and a title strip above the picture (``title``,
    then ``note``, e.g. "black = no match")."""
    img = np.asarray(picture, np.uint8)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    h, w = img.shape[:2]
    scale = max(0.4, min(1.0, h / 600.0))
    thick = 1
    top = picture_offset(img.shape)[0]
    line_h = top - 4
    bar_w, pad = max(14, w // 40), 8
    label_w = int(round(95 * scale))
    canvas = np.full((h + top + 6, w + pad + bar_w + pad + label_w, 3), 255, np.uint8)
    canvas[top:top + h, :w] = img
    # the bar: value hi at the top, lo at the bottom
    values = np.linspace(hi, lo, h)[:, None]
    bar = colorize(np.repeat(values, bar_w, axis=1), lo=lo, hi=hi, reverse=reverse)
    x0 = w + pad
    canvas[top:top + h, x0:x0 + bar_w] = bar
    cv2.rectangle(canvas, (x0, top), (x0 + bar_w - 1, top + h - 1), (0, 0, 0), 1)
    ticks = _ticks(lo, hi)
    step = float(ticks[1] - ticks[0]) if len(ticks) > 1 else (hi - lo)
    for t in ticks:
        y = top + int(round((hi - t) / (hi - lo) * (h - 1)))
        cv2.line(canvas, (x0 + bar_w, y), (x0 + bar_w + 4, y), (0, 0, 0), 1)
        cv2.putText(canvas, _fmt(float(t), step), (x0 + bar_w + 6, y + int(5 * scale)), _FONT,
                    0.45 * scale + 0.1, (0, 0, 0), thick, cv2.LINE_AA)
    cv2.putText(canvas, unit, (x0, top - 6), _FONT, 0.5 * scale + 0.1, (0, 0, 0), thick, cv2.LINE_AA)
    text = title + (f"  ({note})" if note else "")
    if text:
        cv2.putText(canvas, text, (4, line_h - 6), _FONT, 0.55 * scale + 0.1, (0, 0, 0), thick, cv2.LINE_AA)
    return canvas


def disparity_picture(disp: np.ndarray, *, lo: float | None = None, hi: float | None = None,
                      title: str = "disparity", unit: str = "px") -> np.ndarray:
    """BGR picture of a disparity map (pixels, NaN/negative = invalid) with a colour
    bar in ``unit``: large disparity (near) red, invalid black."""
    d = np.asarray(disp, np.float64)
    d = np.where(np.isfinite(d) & (d >= 0), d, np.nan)
    lo, hi = colour_range(d, lo=lo, hi=hi)
    return with_colour_bar(colorize(d, lo=lo, hi=hi), lo=lo, hi=hi, unit=unit, title=title,
                           note="near = red, black = no match")


def depth_picture(depth: np.ndarray, *, lo: float | None = None, hi: float | None = None,
                  title: str = "depth", unit: str = "m") -> np.ndarray:
    """BGR picture of a depth map (``unit``, NaN/<= 0 = none) with a colour bar:
    near blue, far red, none black (the map of :func:`disparity_picture`)."""
    z = np.asarray(depth, np.float64)
    z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    lo, hi = colour_range(z, lo=lo, hi=hi)
    return with_colour_bar(colorize(z, lo=lo, hi=hi), lo=lo, hi=hi, unit=unit,
                           title=title, note="near = blue, black = none")
