"""Back-mapping of rectified matches and linear triangulation (paper sections 2.5, 2.7).

A rectified match is a left pixel ``(u, v)`` with disparity ``d``: its partner
is ``(u - d, v)`` in the rectified right image. The matches are mapped back to
the original (undistorted) images through the inverse rectifying homographies
and triangulated with the original world-frame projection matrices, so the
result is in world units whatever rectification was used (calibrated Fusiello
or uncalibrated Hartley).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from canopy_stereo.geometry.camera import normalize_projection


def apply_homography(H, xy) -> np.ndarray:
    """Map pixels ``xy`` (N, 2) through the 3x3 homography ``H``; returns (N, 2)."""
    H = np.asarray(H, np.float64)
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    w = xy[:, 0] * H[2, 0] + xy[:, 1] * H[2, 1] + H[2, 2]
    x = (xy[:, 0] * H[0, 0] + xy[:, 1] * H[0, 1] + H[0, 2]) / w
    y = (xy[:, 0] * H[1, 0] + xy[:, 1] * H[1, 1] + H[1, 2]) / w
    return np.stack([x, y], axis=1)


def triangulate_dlt(P_left, P_right, x_left, x_right, drop_behind: bool = True) -> np.ndarray:
    """Linear (DLT) triangulation of pixel correspondences, vectorised.

    Solves, for each match, the four equations ``u p3 - p1``, ``v p3 - p2`` of
    both cameras (H&Z sec. 12.2) in least squares for the inhomogeneous point
    ``(X, Y, Z)``; rows are normalised so each equation has unit weight. The
    per-point 3x3 normal equations are solved in a compiled loop (numba).

    Args:
        P_left, P_right: (3, 4) projection matrices (world units -> pixels).
        x_left, x_right: (N, 2) pixel coordinates in the original images.
        drop_behind: set points behind either camera to NaN.

    Returns:
        (N, 3) float64 world points; NaN for degenerate matches (parallel rays)
        and, with ``drop_behind``, for points with non-positive depth.
    """
    P1 = normalize_projection(P_left)
    P2 = normalize_projection(P_right)
    x1 = np.asarray(x_left, np.float64).reshape(-1, 2)
    x2 = np.asarray(x_right, np.float64).reshape(-1, 2)
    n = len(x1)
    if len(x2) != n:
        raise ValueError(f"{n} left points but {len(x2)} right points")
    X = _triangulate_kernel(P1, P2, np.ascontiguousarray(x1), np.ascontiguousarray(x2))
    if drop_behind:
        Xh_w1 = X @ P1[2, :3] + P1[2, 3]
        Xh_w2 = X @ P2[2, :3] + P2[2, 3]
        X[~((Xh_w1 > 0) & (Xh_w2 > 0))] = np.nan
    return X


@njit(cache=True, parallel=True)
def _triangulate_kernel(P1, P2, x1, x2):  # pragma: no cover - compiled
    """Per match: 4 DLT rows (unit-normalised), 3x3 normal equations, Cramer's rule."""
    n = x1.shape[0]
    out = np.empty((n, 3))
    for i in prange(n):
        N = np.zeros((3, 3))
        r = np.zeros(3)
        for k in range(4):
            P = P1 if k < 2 else P2
            x = x1[i] if k < 2 else x2[i]
            c = x[k % 2]
            a0 = c * P[2, 0] - P[k % 2, 0]
            a1 = c * P[2, 1] - P[k % 2, 1]
            a2 = c * P[2, 2] - P[k % 2, 2]
            a3 = c * P[2, 3] - P[k % 2, 3]
            s = 1.0 / np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            a0 *= s
            a1 *= s
            a2 *= s
            a3 *= -s
            N[0, 0] += a0 * a0
            N[0, 1] += a0 * a1
            N[0, 2] += a0 * a2
            N[1, 1] += a1 * a1
            N[1, 2] += a1 * a2
            N[2, 2] += a2 * a2
            r[0] += a0 * a3
            r[1] += a1 * a3
            r[2] += a2 * a3
        a, b, cc = N[0, 0], N[0, 1], N[0, 2]
        d, e, f = N[1, 1], N[1, 2], N[2, 2]
        c00 = d * f - e * e
        c01 = cc * e - b * f
        c02 = b * e - cc * d
        c11 = a * f - cc * cc
        c12 = b * cc - a * e
        c22 = a * d - b * b
        det = a * c00 + b * c01 + cc * c02
        tr = a + d + f
        if not (abs(det) > 1e-12 * tr * tr * tr):
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            out[i, 2] = np.nan
            continue
        out[i, 0] = (c00 * r[0] + c01 * r[1] + c02 * r[2]) / det
        out[i, 1] = (c01 * r[0] + c11 * r[1] + c12 * r[2]) / det
        out[i, 2] = (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det
    return out


def backmap_matches(u, v, d, rect) -> tuple[np.ndarray, np.ndarray]:
    """Map rectified matches ``(u, v) <-> (u - d, v)`` to original pixel coordinates.

    Args:
        u, v, d: equal-length arrays: rectified left pixel and disparity (pixels).
        rect: a :class:`~canopy_stereo.geometry.rectification.Rectification`.

    Returns:
        ``(x_left, x_right)``, each (N, 2), in the original (undistorted) images.
    """
    u = np.asarray(u, np.float64).ravel()
    v = np.asarray(v, np.float64).ravel()
    d = np.asarray(d, np.float64).ravel()
    x_left = apply_homography(rect.H_left_inv, np.stack([u, v], axis=1))
    x_right = apply_homography(rect.H_right_inv, np.stack([u - d, v], axis=1))
    return x_left, x_right


def triangulate_disparity(disp, rect, P_left, P_right) -> np.ndarray:
    """Organized cloud (Hr, Wr, 3) on the rectified left grid from a rectified disparity.

    Pixels with a negative or non-finite disparity, and points behind a camera,
    are NaN. Coordinates are world units of ``P_left``/``P_right``.
    """
    disp = np.asarray(disp, np.float32)
    h, w = disp.shape
    out = np.full((h, w, 3), np.nan)
    valid = np.isfinite(disp) & (disp >= 0)
    vv, uu = np.nonzero(valid)
    if len(uu):
        xl, xr = backmap_matches(uu, vv, disp[vv, uu], rect)
        out[vv, uu] = triangulate_dlt(P_left, P_right, xl, xr)
    return out


def organized_from_disparity(disp, rect, P_left, P_right, image_size, max_jump: float = 1.0,
                             D_left=None):
    """Organized cloud (H, W, 3) on the ORIGINAL left pixel grid from a rectified disparity.

    Each original left pixel ``q`` is mapped into the rectified image
    (``p = H_left q``), its disparity is sampled there, the match
    ``(p, p - d)`` is mapped back through the inverse homographies and
    triangulated. Disparities are bilinearly interpolated where the four
    neighbours are valid and within ``max_jump`` pixels of each other, and taken
    from the nearest pixel otherwise (so depth edges are not smeared).

    ``D_left``: distortion of the left camera; the raw pixel grid is then
    undistorted before it is mapped into the rectified image.

    Returns (H, W, 3) float64 world points, NaN where there is no match.
    """
    w, h = image_size
    disp = np.asarray(disp, np.float32)
    hr, wr = disp.shape
    vv, uu = np.mgrid[0:h, 0:w]
    q = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    if D_left is not None and np.any(D_left):
        from canopy_stereo.geometry.distortion import undistort_pixels

        q = undistort_pixels(P_left, D_left, q)
    p = apply_homography(rect.H_left, q)
    px, py = p[:, 0], p[:, 1]
    inside = (px >= 0) & (py >= 0) & (px <= wr - 1) & (py <= hr - 1)
    idx = np.nonzero(inside)[0]
    px, py = px[idx], py[idx]
    x0 = np.minimum(np.floor(px).astype(np.int64), wr - 2).clip(0)
    y0 = np.minimum(np.floor(py).astype(np.int64), hr - 2).clip(0)
    fx, fy = px - x0, py - y0
    d00, d01 = disp[y0, x0], disp[y0, x0 + 1]
    d10, d11 = disp[y0 + 1, x0], disp[y0 + 1, x0 + 1]
    quad = np.stack([d00, d01, d10, d11], axis=1)
    ok4 = np.all(quad >= 0, axis=1) & (quad.max(axis=1) - quad.min(axis=1) <= max_jump)
    bil = (d00 * (1 - fx) * (1 - fy) + d01 * fx * (1 - fy) + d10 * (1 - fx) * fy + d11 * fx * fy)
    near = disp[np.rint(py).astype(np.int64), np.rint(px).astype(np.int64)]
    d = np.where(ok4, bil, near).astype(np.float64)
    good = d >= 0
    idx, px, py, d = idx[good], px[good], py[good], d[good]
    out = np.full((h * w, 3), np.nan)
    if len(idx):
        x_right = apply_homography(rect.H_right_inv, np.stack([px - d, py], axis=1))
        out[idx] = triangulate_dlt(P_left, P_right, q[idx], x_right)
    return out.reshape(h, w, 3)
