"""Analytic leaves ray-cast through a camera: exact organized clouds with known sizes.

A leaf is an ellipse with semi-axes ``a`` (along its length) and ``b`` (across)
drawn on a plane, or wrapped without stretching onto a cylinder of radius
``radius`` bent along its length or across it (a developable surface, so its
length ``2a``, width ``2b`` and area ``pi a b`` stay exact). Scenes of such
leaves and infinite planes (ground, a wall) are rendered with a depth buffer
into an organized cloud and a label image on the camera's pixel grid. Used by
the tests and benchmarks of :mod:`canopy_stereo.measure`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.geometry.camera import camera_centre, pixel_rays


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64).reshape(3)
    return v / np.linalg.norm(v)


@dataclass
class EllipticLeaf:
    """An elliptic leaf, flat (``radius=None``) or wrapped on a cylinder.

    Attributes:
        centre: (3,) world point at the middle of the leaf.
        length_dir: (3,) direction of the length (major axis) at the centre.
        normal: (3,) leaf normal at the centre (made orthogonal to ``length_dir``).
        a, b: semi-length and semi-width (world units).
        radius: bending radius (world units) or None for a flat leaf.
        bend: ``"length"`` (curved along the midrib) or ``"width"`` (cupped across it).
        bend_sign: +1 bends the ends towards ``+normal``, -1 away from it.
    """

    centre: np.ndarray
    length_dir: np.ndarray
    normal: np.ndarray
    a: float
    b: float
    radius: float | None = None
    bend: str = "length"
    bend_sign: float = 1.0

    @property
    def length(self) -> float:
        """True length ``2a``."""
        return 2.0 * self.a

    @property
    def width(self) -> float:
        """True width ``2b``."""
        return 2.0 * self.b

    @property
    def area(self) -> float:
        """True one-sided area ``pi a b``."""
        return float(np.pi * self.a * self.b)

    def frame(self):
        e1 = _unit(self.length_dir)
        n = np.asarray(self.normal, np.float64)
        n = _unit(n - (n @ e1) * e1)
        e2 = np.cross(n, e1)
        return e1, e2, n

    def intersect(self, C: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Ray parameter ``t`` (N,) of the first hit of rays ``C + t d``; inf for a miss."""
        e1, e2, n = self.frame()
        c = np.asarray(self.centre, np.float64)
        t_out = np.full(len(d), np.inf)
        if self.radius is None:
            denom = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((c - C) @ n) / denom
            X = C + t[:, None] * d
            x, y = (X - c) @ e1, (X - c) @ e2
            hit = (t > 0) & ((x / self.a) ** 2 + (y / self.b) ** 2 <= 1.0)
            t_out[hit] = t[hit]
            return t_out
        R = float(self.radius)
        # curve direction (wrapped) and axis direction of the cylinder
        curve, axis = (e1, e2) if self.bend == "length" else (e2, e1)
        k = self.bend_sign * n
        axis_point = c + R * k
        # solve |(C + t d - axis_point) projected on (curve, k)|^2 = R^2
        q0 = C - axis_point
        q0c, q0k = q0 @ curve, q0 @ k
        dc, dk = d @ curve, d @ k
        A = dc * dc + dk * dk
        B = 2.0 * (q0c * dc + q0k * dk)
        Cq = q0c * q0c + q0k * q0k - R * R
        disc = B * B - 4.0 * A * Cq
        ok = (disc >= 0) & (A > 0)
        sq = np.sqrt(np.where(ok, disc, 0.0))
        for sign in (-1.0, 1.0):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (-B + sign * sq) / (2.0 * A)
            X = C + t[:, None] * d
            q = X - axis_point
            theta = np.arctan2(q @ curve, -(q @ k))
            s = R * theta  # arc coordinate along the curved direction
            w = q @ axis
            x, y = (s, w) if self.bend == "length" else (w, s)
            hit = ok & (t > 0) & ((x / self.a) ** 2 + (y / self.b) ** 2 <= 1.0) & (t < t_out)
            t_out[hit] = t[hit]
        return t_out


@dataclass
class Plane:
    """An infinite plane ``normal . (X - point) = 0`` (ground, wall)."""

    point: np.ndarray
    normal: np.ndarray

    def intersect(self, C: np.ndarray, d: np.ndarray) -> np.ndarray:
        n = _unit(self.normal)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((np.asarray(self.point, np.float64) - C) @ n) / (d @ n)
        return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def render(P, image_size, objects) -> tuple[np.ndarray, np.ndarray]:
    """Ray-cast ``objects`` through camera ``P`` at every pixel centre.

    Args:
        P: (3, 4) camera (world units -> pixels).
        image_size: ``(width, height)``.
        objects: sequence of :class:`EllipticLeaf` / :class:`Plane`.

    Returns:
        ``(organized, labels)``: (H, W, 3) float64 world points (NaN where no
        object is hit) and (H, W) int32 labels, ``i + 1`` for ``objects[i]``
        and 0 for no hit.
    """
    w, h = image_size
    vv, uu = np.mgrid[0:h, 0:w]
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    d = pixel_rays(P, uv)
    C = camera_centre(P)
    best = np.full(len(d), np.inf)
    labels = np.zeros(len(d), np.int32)
    for i, obj in enumerate(objects):
        t = obj.intersect(C, d)
        closer = t < best
        best[closer] = t[closer]
        labels[closer] = i + 1
    X = C + np.where(np.isfinite(best), best, np.nan)[:, None] * d
    return X.reshape(h, w, 3), labels.reshape(h, w)
