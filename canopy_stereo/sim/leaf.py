"""Leaf blade geometry: outline, curved surface and its exact dimensions.

A blade lives in its own frame (world units): ``x`` along the midrib from the
base (``x = 0``) to the tip (``x = span``), ``y`` across the blade and ``z``
along the upper-side normal. The blade is the part of the quadric height field

    z(x, y) = droop * x**2 + rise * x + cup * y**2

inside the outline ``|y| <= half_width_at(x / span)``, with

    half_width_at(s) = half_width * s**a * (1 - s)**b / (s_* ** a * (1 - s_*) ** b),
    s_* = a / (a + b),

``a`` the base exponent (rounded base when below 1) and ``b`` the tip
exponent (pointed tip when below 1; ``a = b = 0.5`` is an ellipse). The
blade is widest (``2 * half_width`` across, in the frame) at ``x = s_* * span``.

True dimensions, as a ruler laid on the leaf measures them:

* length: arc length of the midrib curve ``(x, 0, z(x, 0))`` from base to tip;
* width: arc length of the widest cross-section ``(x_*, y, z(x_*, y))``,
  ``|y| <= half_width``, i.e. the widest extent across the midrib;
* the straight (chord) distances base-tip and edge-edge are given as well, and
  the one-sided surface area by numerical quadrature.

:func:`solve_span` and :func:`solve_half_width` invert the arc lengths so a
leaf can be built with exact true dimensions (the croton's 97 x 160 mm leaf).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import brentq


@lru_cache(maxsize=8)
def _gauss_legendre(nodes: int) -> tuple[np.ndarray, np.ndarray]:
    return np.polynomial.legendre.leggauss(nodes)


def outline_peak(base_exponent: float, tip_exponent: float) -> float:
    """Relative position ``s_*`` in (0, 1) along the midrib where the blade is widest."""
    return base_exponent / (base_exponent + tip_exponent)


def outline_norm(base_exponent: float, tip_exponent: float) -> float:
    """``s_*^a (1 - s_*)^b``: the normaliser that makes the widest half-width 1."""
    s = outline_peak(base_exponent, tip_exponent)
    return s ** base_exponent * (1.0 - s) ** tip_exponent


def half_width_at(s, half_width: float, base_exponent: float, tip_exponent: float) -> np.ndarray:
    """Half-width of the outline at relative midrib positions ``s`` (0 base .. 1 tip).

    Zero outside ``(0, 1)``; world units like ``half_width``.
    """
    s = np.asarray(s, np.float64)
    inside = (s > 0) & (s < 1)
    sc = np.clip(s, 1e-300, 1.0 - 1e-16)
    w = half_width * sc ** base_exponent * (1.0 - sc) ** tip_exponent
    return np.where(inside, w / outline_norm(base_exponent, tip_exponent), 0.0)


def _arc_primitive(u):
    """Antiderivative of ``sqrt(1 + u^2)``."""
    return 0.5 * (u * np.sqrt(1.0 + u * u) + np.arcsinh(u))


def parabola_arc_length(x0: float, x1: float, k: float, g: float) -> float:
    """Arc length of ``z = k x^2 + g x`` for ``x`` in ``[x0, x1]`` (world units)."""
    if abs(k) < 1e-15:
        return float((x1 - x0) * np.sqrt(1.0 + g * g))
    return float((_arc_primitive(2 * k * x1 + g) - _arc_primitive(2 * k * x0 + g)) / (2 * k))


def midrib_length(span: float, droop: float, rise: float) -> float:
    """True leaf length: arc length of the midrib from base to tip (world units)."""
    return parabola_arc_length(0.0, span, droop, rise)


def cross_width(half_width: float, cup: float) -> float:
    """True leaf width: arc length across the widest section (world units)."""
    return parabola_arc_length(-half_width, half_width, cup, 0.0)


def solve_span(length: float, droop: float, rise: float) -> float:
    """Midrib extent ``span`` (frame ``x``) whose midrib arc length is ``length``."""
    f = lambda L: midrib_length(L, droop, rise) - length  # noqa: E731
    return float(brentq(f, 1e-9 * length, length, xtol=1e-13 * length, rtol=1e-15))


def solve_half_width(width: float, cup: float) -> float:
    """Frame half-width whose cross-section arc length is ``width``."""
    f = lambda w: cross_width(w, cup) - width  # noqa: E731
    return float(brentq(f, 1e-9 * width, 0.5 * width, xtol=1e-13 * width, rtol=1e-15))


def surface_height(x, y, droop: float, rise: float, cup: float) -> np.ndarray:
    """Blade height ``z(x, y)`` above the frame's xy plane (world units)."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    return droop * x * x + rise * x + cup * y * y


def surface_area(span: float, half_width: float, base_exponent: float, tip_exponent: float,
                 droop: float, rise: float, cup: float, *, nodes: int = 200) -> float:
    """One-sided area of the curved blade (world units squared), Gauss-Legendre quadrature.

    Integrates ``sqrt(1 + z_x^2 + z_y^2)`` over the outline; ``x`` is mapped
    through ``x = span * (1 - cos(pi t)) / 2`` so the square-root-like ends of
    the outline are resolved (relative error below 1e-7 for webcam-scale leaves).
    """
    gt, gw = _gauss_legendre(nodes)
    t = 0.5 * (gt + 1.0)
    x = 0.5 * span * (1.0 - np.cos(np.pi * t))
    dxdt = 0.5 * span * np.pi * np.sin(np.pi * t)
    hw = half_width_at(x / span, half_width, base_exponent, tip_exponent)
    gy, gwy = _gauss_legendre(48)
    y = hw[:, None] * gy[None, :]
    zx = 2 * droop * x[:, None] + rise
    zy = 2 * cup * y
    integrand = np.sqrt(1.0 + zx * zx + zy * zy)
    inner = (integrand * gwy[None, :]).sum(axis=1) * hw
    return float(0.5 * (inner * dxdt * gw).sum())


def blade_bounds(span: float, half_width: float, droop: float, rise: float,
                 cup: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounds ``(lo, hi)`` (3,) of the blade in its own frame."""
    xs = [0.0, span]
    if abs(droop) > 1e-15:
        xv = -rise / (2 * droop)
        if 0.0 < xv < span:
            xs.append(xv)
    zx = [droop * x * x + rise * x for x in xs]
    zy = [0.0, cup * half_width * half_width]
    lo = np.array([0.0, -half_width, min(zx) + min(zy)])
    hi = np.array([span, half_width, max(zx) + max(zy)])
    return lo, hi
