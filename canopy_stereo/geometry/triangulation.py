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
from numba import njit

from canopy_stereo.geometry.camera import normalize_projection


def apply_homography(H, xy) -> np.ndarray:
    """Map pixels ``xy`` (N, 2) through the 3x3 homography ``H``; returns (N, 2)."""
    H = np.asarray(H, np.float64)
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    w = xy[:, 0] * H[2, 0] + xy[:, 1] * H[2, 1] + H[2, 2]
    x = (xy[:, 0] * H[0, 0] + xy[:, 1] * H[0, 1] + H[0, 2]) / w
    y = (xy[:, 0] * H[1, 0] + xy[:, 1] * H[1, 1] + H[1, 2]) / w
    return np.stack([x, y], axis=1)


def triangulate_dlt(P_left, P_right, x_left, x_right, *, drop_behind: bool = True) -> np.ndarray:
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
    return _triangulate_kernel(P1, P2, np.ascontiguousarray(x1), np.ascontiguousarray(x2), drop_behind)


@njit(cache=True, nogil=True, error_model="numpy")
def _dlt_point(P1, P2, u1, v1, u2, v2, drop_behind, out):  # pragma: no cover - compiled
    """Triangulate one match into ``out`` (3,): 4 unit-normalised DLT rows,
    3x3 normal equations solved by Cramer's rule; NaN if degenerate/behind."""
    n00 = n01 = n02 = n11 = n12 = n22 = 0.0
    r0 = r1 = r2 = 0.0
    for k in range(4):
        P = P1 if k < 2 else P2
        row = k % 2
        if k == 0:
            c = u1
        elif k == 1:
            c = v1
        elif k == 2:
            c = u2
        else:
            c = v2
        a0 = c * P[2, 0] - P[row, 0]
        a1 = c * P[2, 1] - P[row, 1]
        a2 = c * P[2, 2] - P[row, 2]
        a3 = c * P[2, 3] - P[row, 3]
        s = 1.0 / np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        a0 *= s
        a1 *= s
        a2 *= s
        a3 *= -s
        n00 += a0 * a0
        n01 += a0 * a1
        n02 += a0 * a2
        n11 += a1 * a1
        n12 += a1 * a2
        n22 += a2 * a2
        r0 += a0 * a3
        r1 += a1 * a3
        r2 += a2 * a3
    c00 = n11 * n22 - n12 * n12
    c01 = n02 * n12 - n01 * n22
    c02 = n01 * n12 - n02 * n11
    c11 = n00 * n22 - n02 * n02
    c12 = n01 * n02 - n00 * n12
    c22 = n00 * n11 - n01 * n01
    det = n00 * c00 + n01 * c01 + n02 * c02
    tr = n00 + n11 + n22
    if not (abs(det) > 1e-12 * tr * tr * tr):
        out[0] = out[1] = out[2] = np.nan
        return
    x = (c00 * r0 + c01 * r1 + c02 * r2) / det
    y = (c01 * r0 + c11 * r1 + c12 * r2) / det
    z = (c02 * r0 + c12 * r1 + c22 * r2) / det
    if drop_behind:
        w1 = P1[2, 0] * x + P1[2, 1] * y + P1[2, 2] * z + P1[2, 3]
        w2 = P2[2, 0] * x + P2[2, 1] * y + P2[2, 2] * z + P2[2, 3]
        if not (w1 > 0 and w2 > 0):
            out[0] = out[1] = out[2] = np.nan
            return
    out[0] = x
    out[1] = y
    out[2] = z


@njit(cache=True, nogil=True, error_model="numpy")
def _triangulate_kernel(P1, P2, x1, x2, drop_behind):  # pragma: no cover - compiled
    n = x1.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        _dlt_point(P1, P2, x1[i, 0], x1[i, 1], x2[i, 0], x2[i, 1], drop_behind, out[i])
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _backmap_match(u, v, d, Hl_inv, Hr_inv):  # pragma: no cover - compiled
    """Original pixels ``(u1, v1, u2, v2)`` of the rectified match ``(u, v) <-> (u - d, v)``."""
    z1 = Hl_inv[2, 0] * u + Hl_inv[2, 1] * v + Hl_inv[2, 2]
    u1 = (Hl_inv[0, 0] * u + Hl_inv[0, 1] * v + Hl_inv[0, 2]) / z1
    v1 = (Hl_inv[1, 0] * u + Hl_inv[1, 1] * v + Hl_inv[1, 2]) / z1
    ur = u - d
    z2 = Hr_inv[2, 0] * ur + Hr_inv[2, 1] * v + Hr_inv[2, 2]
    u2 = (Hr_inv[0, 0] * ur + Hr_inv[0, 1] * v + Hr_inv[0, 2]) / z2
    v2 = (Hr_inv[1, 0] * ur + Hr_inv[1, 1] * v + Hr_inv[1, 2]) / z2
    return u1, v1, u2, v2


@njit(cache=True, nogil=True, error_model="numpy")
def _rectified_grid_kernel(disp, Hl_inv, Hr_inv, P1, P2):  # pragma: no cover - compiled
    h, w = disp.shape
    out = np.full((h, w, 3), np.nan)
    for v in range(h):
        for u in range(w):
            d = disp[v, u]
            if not (d >= 0) or not np.isfinite(d):
                continue
            u1, v1, u2, v2 = _backmap_match(u, v, d, Hl_inv, Hr_inv)
            _dlt_point(P1, P2, u1, v1, u2, v2, True, out[v, u])
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _rectified_points_kernel(disp, mask, Hl_inv, Hr_inv, P1, P2, scale, organized):  # pragma: no cover
    """One pass over the rectified grid: valid pixels -> float32 points (scaled) + flat index."""
    h, w = disp.shape
    n_max = h * w
    pts = np.empty((n_max, 3), np.float32)
    index = np.empty(n_max, np.int32)
    xyz = np.empty(3)
    use_mask = mask.shape[0] == h
    n = 0
    for v in range(h):
        for u in range(w):
            d = disp[v, u]
            ok = d >= 0 and np.isfinite(d) and (not use_mask or mask[v, u] != 0)
            if ok:
                u1, v1, u2, v2 = _backmap_match(u, v, d, Hl_inv, Hr_inv)
                _dlt_point(P1, P2, u1, v1, u2, v2, True, xyz)
                ok = np.isfinite(xyz[0])
            if ok:
                pts[n, 0] = xyz[0] * scale
                pts[n, 1] = xyz[1] * scale
                pts[n, 2] = xyz[2] * scale
            elif organized:
                pts[n, 0] = pts[n, 1] = pts[n, 2] = np.nan
            else:
                continue
            index[n] = v * w + u
            n += 1
    return pts[:n], index[:n]


def kernel_mask(mask, shape, *, contiguous: bool = True) -> np.ndarray:
    """``mask`` as the compiled kernels take it: uint8 of ``shape`` (non-zero = keep), or an
    empty (0, 0) array for "no mask" (``contiguous`` False: a uint8 window of a larger mask is
    passed as it is, not copied). Raises ValueError when the shapes differ."""
    if mask is None:
        return np.zeros((0, 0), np.uint8)
    m = np.ascontiguousarray(mask) if contiguous else np.asarray(mask)
    if m.shape != tuple(shape):
        raise ValueError(f"mask {m.shape} does not match disparity {tuple(shape)}")
    return m if m.dtype == np.uint8 else (m != 0).astype(np.uint8)


def triangulate_disparity_points(disp, rect, P_left, P_right, *, scale: float = 1.0, mask=None,
                                 organized: bool = False):
    """Points of the valid pixels of a rectified disparity, in one compiled pass.

    The same back-mapping and DLT triangulation as :func:`triangulate_disparity`
    (to the last bit of the float64 computation), without the float64
    (Hr, Wr, 3) intermediate: what a live node needs per frame.

    Args:
        disp: (Hr, Wr) rectified disparity ``u_left - u_right`` (pixels); negative
            or non-finite = no match.
        rect: the :class:`~canopy_stereo.geometry.rectification.Rectification`.
        P_left, P_right: (3, 4) world-frame projection matrices.
        scale: factor applied to the world coordinates (e.g. 0.001 for mm -> m).
        mask: optional (Hr, Wr) array; pixels where it is 0 are dropped.
        organized: keep every pixel (NaN where none) instead of only valid ones.

    Returns:
        ``(points, index)``: float32 (N, 3) world points times ``scale`` and
        int32 (N,) flat indices ``v * Wr + u`` of their rectified left pixels
        (N = Hr * Wr and ``index = arange`` when ``organized``).
    """
    disp = np.ascontiguousarray(disp, dtype=np.float32)
    mask_arr = kernel_mask(mask, disp.shape)
    return _rectified_points_kernel(disp, mask_arr, np.asarray(rect.H_left_inv, np.float64),
                                    np.asarray(rect.H_right_inv, np.float64),
                                    normalize_projection(P_left), normalize_projection(P_right),
                                    float(scale), bool(organized))


@njit(cache=True, nogil=True, error_model="numpy")
def _original_grid_kernel(disp, qx, qy, Hl, Hr_inv, P1, P2, max_jump):  # pragma: no cover - compiled
    hr, wr = disp.shape
    h, w = qx.shape
    out = np.full((h, w, 3), np.nan)
    for i in range(h):
        for j in range(w):
            x, y = qx[i, j], qy[i, j]
            z = Hl[2, 0] * x + Hl[2, 1] * y + Hl[2, 2]
            px = (Hl[0, 0] * x + Hl[0, 1] * y + Hl[0, 2]) / z
            py = (Hl[1, 0] * x + Hl[1, 1] * y + Hl[1, 2]) / z
            if not (px >= 0 and py >= 0 and px <= wr - 1 and py <= hr - 1):
                continue
            x0 = min(int(px), wr - 2)
            y0 = min(int(py), hr - 2)
            fx, fy = px - x0, py - y0
            d00, d01 = disp[y0, x0], disp[y0, x0 + 1]
            d10, d11 = disp[y0 + 1, x0], disp[y0 + 1, x0 + 1]
            lo = min(min(d00, d01), min(d10, d11))
            hi = max(max(d00, d01), max(d10, d11))
            if lo >= 0 and hi - lo <= max_jump:
                d = (d00 * (1 - fx) * (1 - fy) + d01 * fx * (1 - fy)
                     + d10 * (1 - fx) * fy + d11 * fx * fy)
            else:
                d = disp[int(py + 0.5), int(px + 0.5)]
            if not (d >= 0) or not np.isfinite(d):
                continue
            ur = px - d
            z2 = Hr_inv[2, 0] * ur + Hr_inv[2, 1] * py + Hr_inv[2, 2]
            u2 = (Hr_inv[0, 0] * ur + Hr_inv[0, 1] * py + Hr_inv[0, 2]) / z2
            v2 = (Hr_inv[1, 0] * ur + Hr_inv[1, 1] * py + Hr_inv[1, 2]) / z2
            _dlt_point(P1, P2, x, y, u2, v2, True, out[i, j])
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

    Each pixel ``(u, v)`` with disparity ``d >= 0`` is mapped back to the
    original images (``H_left^-1 (u, v)``, ``H_right^-1 (u - d, v)``) and
    triangulated with the world-frame matrices. Pixels with a negative or
    non-finite disparity, and points behind a camera, are NaN. Coordinates are
    world units of ``P_left``/``P_right``.
    """
    disp = np.ascontiguousarray(disp, dtype=np.float32)
    return _rectified_grid_kernel(disp, rect.H_left_inv, rect.H_right_inv,
                                  normalize_projection(P_left), normalize_projection(P_right))


def organized_from_disparity(disp, rect, P_left, P_right, image_size, *, max_jump: float = 1.0,
                             D_left=None, distortion_model: str | None = None):
    """Organized cloud (H, W, 3) on the ORIGINAL left pixel grid from a rectified disparity.

    Each original left pixel ``q`` is mapped into the rectified image
    (``p = H_left q``), its disparity is sampled there, the match
    ``(p, p - d)`` is mapped back through the inverse homographies and
    triangulated. Disparities are bilinearly interpolated where the four
    neighbours are valid and within ``max_jump`` pixels of each other, and taken
    from the nearest pixel otherwise (so depth edges are not smeared).

    ``D_left``: distortion of the left camera; the raw pixel grid is then
    undistorted (lens model ``distortion_model``, None = OpenCV's) before it is mapped
    into the rectified image.

    Returns (H, W, 3) float64 world points, NaN where there is no match.
    """
    w, h = image_size
    disp = np.ascontiguousarray(disp, dtype=np.float32)
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
    if D_left is not None and np.any(D_left):
        from canopy_stereo.geometry.distortion import undistort_pixels

        q = undistort_pixels(P_left, D_left, np.stack([uu.ravel(), vv.ravel()], axis=1),
                             model=distortion_model)
        uu, vv = q[:, 0].reshape(h, w), q[:, 1].reshape(h, w)
    return _original_grid_kernel(disp, np.ascontiguousarray(uu), np.ascontiguousarray(vv),
                                 np.asarray(rect.H_left, np.float64), rect.H_right_inv,
                                 normalize_projection(P_left), normalize_projection(P_right),
                                 float(max_jump))
