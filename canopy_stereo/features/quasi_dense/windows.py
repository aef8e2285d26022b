"""Window statistics of quasi-dense matching: ZNCC, texture along the epipolar lines, aperture.

Pixels: ``u`` right, ``v`` down, top-left pixel centre at (0, 0).
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

# ----------------------------------------------------------------------------------------------
# Window statistics for ZNCC


def epipoles(F: np.ndarray):
    """Left and right epipoles (homogeneous, unit norm) of F: ``F e_l = 0``, ``F^T e_r = 0``."""
    _, _, vt = np.linalg.svd(F)
    e_left = vt[-1]
    _, _, vt = np.linalg.svd(F.T)
    e_right = vt[-1]
    return e_left / np.linalg.norm(e_left), e_right / np.linalg.norm(e_right)


def _epipolar_gradients(img: np.ndarray, epipole):
    """Intensity gradient (Sobel, grey levels per pixel) of a float (H, W) image along and
    across the epipolar line through each pixel (direction from the epipole, homogeneous
    3-vector, to the pixel; either sign): ``(g_along, g_across)``, float64 (H, W) each."""
    h, w = img.shape
    gx = cv2.Sobel(img, cv2.CV_64F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(img, cv2.CV_64F, 0, 1, ksize=3) / 8.0
    ex, ey, ew = (float(c) for c in np.asarray(epipole, np.float64).ravel())
    u = np.arange(w, dtype=np.float64)[None, :]
    v = np.arange(h, dtype=np.float64)[:, None]
    dx = ew * u - ex
    dy = ew * v - ey
    norm = np.hypot(dx, dy)
    norm[norm < 1e-12] = 1.0
    dx, dy = dx / norm, dy / norm
    return gx * dx + gy * dy, gy * dx - gx * dy


def texture_map(gray: np.ndarray, half_window: int, *, epipole=None) -> np.ndarray:
    """Texture of each pixel's matching window, grey levels per pixel, float64 (H, W).

    Without an epipole: the largest absolute difference to a 4-neighbour
    (Lhuillier & Quan's measure). With the image's epipole (homogeneous 3-vector,
    from F): the window mean of ``|grad I . e|``, the intensity gradient along the
    epipolar line through the pixel. Windows whose only structure runs along the
    epipolar line (the aperture problem: e.g. horizontal edges in a rectified pair)
    then score low and are not propagated into.
    """
    img = np.asarray(gray, dtype=np.float64)
    if epipole is None:
        texture = np.zeros_like(img)
        dx = np.abs(np.diff(img, axis=1))
        dy = np.abs(np.diff(img, axis=0))
        texture[:, :-1] = np.maximum(texture[:, :-1], dx)
        texture[:, 1:] = np.maximum(texture[:, 1:], dx)
        texture[:-1, :] = np.maximum(texture[:-1, :], dy)
        texture[1:, :] = np.maximum(texture[1:, :], dy)
        return texture
    g_a, _ = _epipolar_gradients(img, epipole)
    along = np.abs(g_a)
    k = 2 * half_window + 1
    return cv2.boxFilter(along, cv2.CV_64F, (k, k), normalize=True, borderType=cv2.BORDER_REFLECT)


def aperture_coupling(gray: np.ndarray, half_window: int, epipole) -> np.ndarray:
    """How strongly a window's displacement along the epipolar line depends on an error
    across it, per pixel, float64 (H, W) (dimensionless; 0 = independent).

    With ``g_a`` / ``g_n`` the intensity gradient along / across the epipolar line through
    the pixel (direction from the image's epipole, homogeneous 3-vector), summed over the
    ``(2 half_window + 1)``-pixel window: ``|sum g_a g_n| / sum g_a^2``. Matching a window
    with a vertical offset ``dv`` (an integer-pixel match of a pair whose rows differ by a
    fraction of a pixel) shifts the best horizontal position by about ``coupling * dv``: a
    window whose only structure is an edge slanted ``theta`` from the epipolar line has
    coupling ``1 / tan(theta)`` (0 for an edge across the line, 1 at 45 degrees, large for
    edges nearly along it); windows with texture in two directions stay near 0. Where the
    window has no gradient along the line the value is ``inf``.
    """
    img = np.asarray(gray, dtype=np.float64)
    g_a, g_n = _epipolar_gradients(img, epipole)
    k = 2 * half_window + 1
    saa = cv2.boxFilter(g_a * g_a, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_REFLECT)
    san = cv2.boxFilter(g_a * g_n, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_REFLECT)
    out = np.full_like(img, np.inf)
    ok = saa > 1e-9
    out[ok] = np.abs(san[ok]) / saa[ok]
    return out


def window_statistics(gray: np.ndarray, half_window: int, *, epipole=None):
    """Per-pixel window mean, inverse window norm and texture of a grey image.

    Args:
        gray: (H, W) uint8 or float image.
        half_window: ZNCC window is ``(2 * half_window + 1)`` pixels square.
        epipole: the image's epipole for the directional texture (see :func:`texture_map`).

    Returns:
        ``(image, mean, inv_norm, texture)``, float64 (H, W) each: the image as
        float, the window mean, ``1 / sqrt(sum (I - mean)^2)`` over the window
        (0 for flat windows and within ``half_window`` of the border), and the
        texture from :func:`texture_map`.
    """
    img = np.asarray(gray, dtype=np.float64)
    k = 2 * half_window + 1
    n = float(k * k)
    s1 = cv2.boxFilter(img, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    s2 = cv2.boxFilter(img * img, cv2.CV_64F, (k, k), normalize=False, borderType=cv2.BORDER_CONSTANT)
    mean = s1 / n
    var_sum = s2 - s1 * mean
    inv_norm = np.zeros_like(img)
    ok = var_sum > 1e-6 * n
    inv_norm[ok] = 1.0 / np.sqrt(var_sum[ok])
    inv_norm[:half_window, :] = 0.0
    inv_norm[-half_window:, :] = 0.0
    inv_norm[:, :half_window] = 0.0
    inv_norm[:, -half_window:] = 0.0
    return img, mean, inv_norm, texture_map(img, half_window, epipole=epipole)


@njit(cache=True)
def _zncc(L, R, x, y, xr, yr, hw, mean_l, inv_l, mean_r, inv_r):
    """ZNCC of the (2hw+1)^2 windows centred on left (x, y) and right (xr, yr)."""
    il = inv_l[y, x]
    ir = inv_r[yr, xr]
    if il == 0.0 or ir == 0.0:
        return -1.0
    s = 0.0
    for j in range(-hw, hw + 1):
        for i in range(-hw, hw + 1):
            s += L[y + j, x + i] * R[yr + j, xr + i]
    n = (2 * hw + 1) * (2 * hw + 1)
    return (s - n * mean_l[y, x] * mean_r[yr, xr]) * il * ir


@njit(cache=True)
def zncc_at(L, R, xl, yl, xr, yr, hw, mean_l, inv_l, mean_r, inv_r):
    """ZNCC of many integer pixel pairs (arrays of equal length); -1 outside the valid area."""
    n = len(xl)
    out = np.full(n, -1.0)
    H, W = L.shape
    for k in range(n):
        x, y, a, b = xl[k], yl[k], xr[k], yr[k]
        if hw <= x < W - hw and hw <= y < H - hw and hw <= a < W - hw and hw <= b < H - hw:
            out[k] = _zncc(L, R, x, y, a, b, hw, mean_l, inv_l, mean_r, inv_r)
    return out
