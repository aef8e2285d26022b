"""Fundamental matrix from point matches (robust estimation) and epipolar distances.

Convention: ``x_right^T F x_left = 0`` for homogeneous pixel coordinates, so
``F @ x_left`` is the epipolar line of ``x_left`` in the right image.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, MatchingError

#: Fewest matches accepted for a fundamental matrix (the 8-point algorithm's minimum).
MIN_MATCHES_F = 8

_ROBUST_METHODS = {
    "ransac": cv2.FM_RANSAC,
    "magsac": getattr(cv2, "USAC_MAGSAC", None),
}


def _as_points(x, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise CanopyStereoError(f"{name} must be an (N, 2) array of pixels, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise CanopyStereoError(f"{name} holds NaN or infinite coordinates")
    return x


def estimate_fundamental(x_left, x_right, *, method: str = "ransac", threshold_px: float = 1.0,
                         confidence: float = 0.999, max_iters: int = 5000):
    """Robustly fit F to matches: ``(F, inlier_mask)``.

    Args:
        x_left, x_right: (N, 2) matched pixels ``(u, v)`` of the left/right image.
        method: ``"ransac"`` (7-point RANSAC, then 8-point on the inliers) or
            ``"magsac"`` (OpenCV USAC MAGSAC++, with degeneracy checks).
        threshold_px: inlier threshold, pixels of distance to the epipolar line.
        confidence: RANSAC confidence.
        max_iters: iteration cap.

    Returns:
        ``F`` (3, 3) float64 with ``x_r^T F x_l = 0`` and unit Frobenius norm (the
        robust estimate re-fitted by least squares on its inliers), and
        ``inlier_mask`` (N,) bool: matches within ``threshold_px`` of their epipolar
        line in both images.

    Raises:
        MatchingError: fewer than 8 matches, or no F could be found.
        CanopyStereoError: unknown method, mismatched or malformed inputs.
    """
    x_left = _as_points(x_left, "x_left")
    x_right = _as_points(x_right, "x_right")
    if len(x_left) != len(x_right):
        raise CanopyStereoError(
            f"x_left and x_right hold different numbers of points ({len(x_left)} vs {len(x_right)})")
    if method not in _ROBUST_METHODS:
        raise CanopyStereoError(
            f"unknown F estimation method {method!r}; choose one of {', '.join(_ROBUST_METHODS)}")
    flag = _ROBUST_METHODS[method]
    if flag is None:
        raise CanopyStereoError(f"F estimation method {method!r} needs OpenCV >= 4.5 (USAC)")
    if threshold_px <= 0:
        raise CanopyStereoError(f"threshold_px must be positive, got {threshold_px}")
    n = len(x_left)
    if n < MIN_MATCHES_F:
        raise MatchingError(f"need at least {MIN_MATCHES_F} matches to estimate F, got {n}")
    F, mask = cv2.findFundamentalMat(x_left.reshape(-1, 1, 2), x_right.reshape(-1, 1, 2), flag,
                                     float(threshold_px), float(confidence), int(max_iters))
    if F is None or F.shape != (3, 3) or mask is None:
        raise MatchingError(f"no fundamental matrix fits the {n} matches (degenerate configuration)")
    F = F / np.linalg.norm(F)
    inliers = mask.ravel().astype(bool)
    F, inliers = _refine_on_inliers(F, inliers, x_left, x_right, float(threshold_px))
    if inliers.sum() < MIN_MATCHES_F:
        raise MatchingError(
            f"only {int(inliers.sum())} of {n} matches agree with one fundamental matrix")
    return F, inliers


def _refine_on_inliers(F, inliers, x_left, x_right, threshold_px, rounds: int = 3):
    """Least-squares (normalised 8-point) re-fit of F on its inliers, then re-select the
    inliers (symmetric epipolar distance <= threshold); kept only while the inlier
    count does not drop."""
    for _ in range(rounds):
        if inliers.sum() < MIN_MATCHES_F:
            break
        F_ls, _ = cv2.findFundamentalMat(x_left[inliers].reshape(-1, 1, 2),
                                         x_right[inliers].reshape(-1, 1, 2), cv2.FM_8POINT)
        if F_ls is None or F_ls.shape != (3, 3):
            break
        F_ls = F_ls / np.linalg.norm(F_ls)
        new = epipolar_distance(F_ls, x_left, x_right, symmetric=True) <= threshold_px
        if new.sum() < inliers.sum():
            break
        stable = np.array_equal(new, inliers)
        F, inliers = F_ls, new
        if stable:
            break
    return F, epipolar_distance(F, x_left, x_right, symmetric=True) <= threshold_px


def epipolar_distance(F: np.ndarray, x_left, x_right, *, symmetric: bool = False) -> np.ndarray:
    """Distance (pixels) of each ``x_right`` from the epipolar line ``F x_left``.

    With ``symmetric=True`` returns the larger of that and the distance of
    ``x_left`` from ``F^T x_right`` in the left image. Shapes: (N, 2) -> (N,).
    """
    xl = np.asarray(x_left, dtype=np.float64).reshape(-1, 2)
    xr = np.asarray(x_right, dtype=np.float64).reshape(-1, 2)
    hl = np.column_stack([xl, np.ones(len(xl))])
    hr = np.column_stack([xr, np.ones(len(xr))])
    lines_r = hl @ F.T                        # (N, 3): F x_l
    num = np.abs(np.sum(lines_r * hr, axis=1))
    d_right = num / np.maximum(np.hypot(lines_r[:, 0], lines_r[:, 1]), 1e-12)
    if not symmetric:
        return d_right
    lines_l = hr @ F                          # (N, 3): F^T x_r
    d_left = num / np.maximum(np.hypot(lines_l[:, 0], lines_l[:, 1]), 1e-12)
    return np.maximum(d_left, d_right)
