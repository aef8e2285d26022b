"""Lens distortion with OpenCV's coefficient order ``[k1, k2, p1, p2, k3]``.

Pixels are mapped through the full intrinsics ``K`` of a projection matrix
(including skew), so "ideal" pixels are exactly those a pinhole ``P`` predicts.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.geometry.camera import decompose_projection


def _distortion_terms(D):
    D = np.zeros(5) if D is None else np.asarray(D, np.float64).ravel()
    k3 = D[4] if len(D) > 4 else 0.0
    return D[0], D[1], D[2], D[3], k3


def _distort_normalised(x, y, D):
    k1, k2, p1, p2, k3 = _distortion_terms(D)
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd


def distort_pixels(P, D, xy) -> np.ndarray:
    """Ideal (pinhole) pixels (N, 2) -> distorted pixels with OpenCV's model.

    Uses the full intrinsics ``K`` of ``P`` (including skew) and the
    coefficients ``D = [k1, k2, p1, p2, k3]`` (higher-order terms are ignored).
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if D is None or not np.any(D):
        return xy
    K = decompose_projection(P).K
    n = np.linalg.solve(K, np.column_stack([xy, np.ones(len(xy))]).T)
    xd, yd = _distort_normalised(n[0] / n[2], n[1] / n[2], D)
    out = K @ np.vstack([xd, yd, np.ones_like(xd)])
    return (out[:2] / out[2]).T


def undistort_pixels(P, D, xy, *, iterations: int = 30) -> np.ndarray:
    """Distorted pixels (N, 2) -> ideal pixels: inverse of :func:`distort_pixels`.

    Fixed-point iteration on normalised coordinates (as OpenCV's
    ``undistortPoints``), accurate to well below 1e-6 px for webcam lenses.
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if D is None or not np.any(D):
        return xy
    K = decompose_projection(P).K
    n = np.linalg.solve(K, np.column_stack([xy, np.ones(len(xy))]).T)
    xd, yd = n[0] / n[2], n[1] / n[2]
    k1, k2, p1, p2, k3 = _distortion_terms(D)
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd - dx) / radial
        y = (yd - dy) / radial
    out = K @ np.vstack([x, y, np.ones_like(x)])
    return (out[:2] / out[2]).T
