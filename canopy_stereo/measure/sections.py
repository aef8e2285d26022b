"""Plane sections of a grid surface and their lengths along the surface.

A leaf's length and width are lengths of curves on its surface: the curve
where a plane cuts the leaf (for the length, the plane through both ends and
the leaf normal, which contains the midrib of a leaf bent or folded about it;
for the width, the plane across the midrib). The cut is found on every grid
edge whose two surface points lie on opposite sides of the plane; the leaf
outline is where a smoothed mask crosses one half (:func:`outline_field`),
so the curve runs to the edge of the leaf with sub-pixel precision.

Within the plane the curve is written as a height ``h(a)`` over a coordinate
``a`` along it and fitted by a low-order polynomial; its arc length is
integrated by Gauss-Legendre quadrature. The polynomial averages out the
residual matching noise of a reconstruction, which would otherwise add
length (a noisy polyline is always longer than the curve it samples), and is
exact for straight sections.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.polynomial import chebyshev as cheb

from canopy_stereo.measure.surface import GridSurface

#: Highest degree of the height polynomial of a section.
SECTION_DEGREE = 6

_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(64)


#: Gaussian scale (pixels) that smooths the pixel steps of a mask's outline.
OUTLINE_SIGMA_PX = 0.6


def outline_field(inside: np.ndarray, sigma: float = OUTLINE_SIGMA_PX) -> np.ndarray:
    """(h, w) field that is zero on a sub-pixel outline of a binary mask.

    The mask blurred by a Gaussian of ``sigma`` pixels, minus 0.5: positive
    inside, negative outside. Between an inside and an outside pixel centre it
    crosses zero half-way on straight edges; the blur replaces the staircase
    of a slanted or curved outline by a smooth curve through its middle (on
    analytic leaves this halves the worst length error of the plain half-way
    rule). Pixels beyond the array count as outside.
    """
    m = inside.astype(np.float64)
    r = int(np.ceil(3 * sigma))
    blurred = cv2.GaussianBlur(m, (2 * r + 1, 2 * r + 1), sigma, borderType=cv2.BORDER_CONSTANT)
    return blurred - 0.5


def plane_cut(surface: GridSurface, phi: np.ndarray, point: np.ndarray, normal: np.ndarray):
    """Points where the plane ``(X - point) . normal = 0`` cuts the grid surface.

    Each grid edge (horizontal or vertical pixel pair inside the surface's
    domain) whose ends lie on opposite sides contributes one point, linearly
    interpolated, with the interpolated outline field ``phi``.

    Returns:
        ``(P, phi)``: (K, 3) world points on the plane and (K,) values of the
        outline field (negative outside the leaf).
    """
    X, dom = surface.X, surface.domain
    s = np.where(dom, np.einsum("hwk,k->hw", np.nan_to_num(X), normal) - float(point @ normal), np.nan)
    pts, phis = [], []
    for sa, sb, Xa, Xb, pa, pb in (
        (s[:, :-1], s[:, 1:], X[:, :-1], X[:, 1:], phi[:, :-1], phi[:, 1:]),
        (s[:-1, :], s[1:, :], X[:-1, :], X[1:, :], phi[:-1, :], phi[1:, :]),
    ):
        with np.errstate(invalid="ignore"):
            cross = (sa * sb <= 0) & (sa != sb)
        idx = np.nonzero(cross)
        if not len(idx[0]):
            continue
        a, b = sa[idx], sb[idx]
        t = (a / (a - b))[:, None]
        pts.append(Xa[idx] + t * (Xb[idx] - Xa[idx]))
        phis.append(pa[idx] + t[:, 0] * (pb[idx] - pa[idx]))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0)
    return np.concatenate(pts), np.concatenate(phis)


@dataclass
class Section:
    """A measured section curve.

    Attributes:
        length: arc length along the surface between the two ends (world units).
        ends: (2, 3) world points where the curve leaves the leaf.
        chord: straight distance between the ends.
        a_range: ``(a0, a1)`` coordinates of the ends along ``along``.
        origin, along, up: the in-plane frame: a point, the direction of ``a``
            and the direction of ``h`` (unit vectors).
        coef: Chebyshev coefficients of ``h(a)`` on the domain ``a_range``.
        complete: False when a side ran out of surface before reaching the
            leaf outline (the leaf touches the image border or a big hole).
    """

    length: float
    ends: np.ndarray
    chord: float
    a_range: tuple[float, float]
    origin: np.ndarray
    along: np.ndarray
    up: np.ndarray
    coef: np.ndarray
    complete: bool

    def _x(self, a):
        a0, a1 = self.a_range
        return (2.0 * np.asarray(a, np.float64) - (a0 + a1)) / max(a1 - a0, 1e-300)

    def height(self, a) -> np.ndarray:
        """Height ``h(a)`` of the fitted curve above ``origin`` along ``up``."""
        return cheb.chebval(self._x(a), self.coef)

    def point(self, a) -> np.ndarray:
        """(N, 3) world points of the fitted curve at coordinates ``a``."""
        a = np.atleast_1d(np.asarray(a, np.float64))
        return self.origin + a[:, None] * self.along + self.height(a)[:, None] * self.up

    def tangent(self, a) -> np.ndarray:
        """(N, 3) unit tangents of the fitted curve at ``a`` (pointing to larger ``a``)."""
        a = np.atleast_1d(np.asarray(a, np.float64))
        a0, a1 = self.a_range
        dh = cheb.chebval(self._x(a), cheb.chebder(self.coef)) * 2.0 / max(a1 - a0, 1e-300)
        t = self.along + dh[:, None] * self.up
        return t / np.linalg.norm(t, axis=1, keepdims=True)


def _walk(a: np.ndarray, phi: np.ndarray, P: np.ndarray, i0: int, step: int, max_gap: float):
    """From index ``i0`` walk in ``step`` direction to where ``phi`` turns negative.

    Returns ``(a_end, reached_outline, last_index)``: the coordinate where the
    outline is crossed (interpolated), whether it was reached before a gap or
    the end of the cut, and the index of the last point visited.
    """
    j = i0
    n = len(a)
    while 0 <= j + step < n:
        k = j + step
        if np.linalg.norm(P[k] - P[j]) > max_gap:
            return a[j], False, j
        if phi[k] < 0:
            f = phi[j] / (phi[j] - phi[k])
            return a[j] + f * (a[k] - a[j]), True, k
        j = k
    return a[j], False, j


def measure_section(surface: GridSurface, phi: np.ndarray, origin: np.ndarray, plane_normal: np.ndarray,
                    up_hint: np.ndarray, *, start: float = 0.0, along_hint: np.ndarray | None = None,
                    max_gap: float | None = None, degree: int = SECTION_DEGREE) -> Section | None:
    """Length along the surface of the plane section through ``origin``.

    Args:
        surface: the smoothed leaf surface (crop).
        phi: (h, w) outline field of the leaf (:func:`outline_field`) on the same crop.
        origin: (3,) a point of the plane (world units).
        plane_normal: (3,) normal of the cutting plane.
        up_hint: (3,) direction of heights in the plane (the leaf normal);
            its component along ``plane_normal`` is removed.
        start: coordinate ``a`` (along the section, from ``origin``) of the
            part of the cut to measure: the connected run of cut points around
            it, up to the leaf outline on both sides.
        along_hint: optional (3,) direction the coordinate ``a`` should follow.
        max_gap: largest 3D step between consecutive cut points that still
            counts as connected (default: 8 median steps).
        degree: highest degree of the height polynomial.

    Returns:
        a :class:`Section`, or None when the plane misses the leaf.
    """
    m = plane_normal / np.linalg.norm(plane_normal)
    up = up_hint - (up_hint @ m) * m
    if np.linalg.norm(up) < 1e-9:
        return None
    up /= np.linalg.norm(up)
    along = np.cross(up, m)
    if along_hint is not None and along @ along_hint < 0:
        along = -along
    P, ph = plane_cut(surface, phi, origin, m)
    if len(P) < 4:
        return None
    rel = P - origin
    a = rel @ along
    order = np.argsort(a, kind="stable")
    a, P, ph, h = a[order], P[order], ph[order], (rel @ up)[order]
    inside = np.nonzero(ph >= 0)[0]
    if not len(inside):
        return None
    i0 = int(inside[np.argmin(np.abs(a[inside] - start))])
    steps = np.linalg.norm(np.diff(P, axis=0), axis=1)
    if max_gap is None:
        med = np.median(steps[steps > 0]) if np.any(steps > 0) else 1.0
        max_gap = 8.0 * med + 1e-12
    a_lo, ok_lo, i_lo = _walk(a, ph, P, i0, -1, max_gap)
    a_hi, ok_hi, i_hi = _walk(a, ph, P, i0, +1, max_gap)
    if a_hi <= a_lo:
        return None
    # the connected run and a few points of the rim beyond the outline
    sel = np.zeros(len(a), bool)
    sel[max(i_lo - 4, 0):i_hi + 5] = True
    x = (2.0 * a[sel] - (a_lo + a_hi)) / (a_hi - a_lo)
    deg = int(min(degree, max(1, sel.sum() // 8)))
    coef = cheb.chebfit(x, h[sel], deg)
    # arc length of (a, h(a)) over [a_lo, a_hi]
    xq = _GL_NODES
    dh = cheb.chebval(xq, cheb.chebder(coef)) * 2.0 / (a_hi - a_lo)
    length = 0.5 * (a_hi - a_lo) * float(np.sum(_GL_WEIGHTS * np.sqrt(1.0 + dh * dh)))
    sec = Section(length=length, ends=np.zeros((2, 3)), chord=0.0, a_range=(float(a_lo), float(a_hi)),
                  origin=np.asarray(origin, np.float64), along=along, up=up, coef=coef,
                  complete=bool(ok_lo and ok_hi))
    sec.ends = sec.point([a_lo, a_hi])
    sec.chord = float(np.linalg.norm(sec.ends[1] - sec.ends[0]))
    return sec
