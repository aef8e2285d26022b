"""Synthetic rectified stereo pairs with exactly known disparity (tests, demos).

The scene is a textured plane ``d(u, v) = a*u + b*v + c`` seen by the left camera:
the left image samples a smooth random texture ``T`` at ``(u, v)``; the right image
at column ``x`` shows the scene point whose left column ``u`` satisfies
``x = u - d(u, v)``, i.e. ``u = (x + b*v + c) / (1 - a)``. Sampling uses bicubic
interpolation of ``T``, so sub-pixel disparities are rendered faithfully.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError


def random_texture(width: int, height: int, seed: int = 0, blur_sigma: float = 1.0,
                   margin: int = 0) -> np.ndarray:
    """float32 (height, width + 2*margin) smooth random texture in 0..255."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0.0, 1.0, size=(height, width + 2 * margin)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), blur_sigma) if blur_sigma > 0 else noise
    tex -= tex.min()
    tex *= 255.0 / max(float(tex.max()), 1e-6)
    return tex


def plane_pair(width: int = 200, height: int = 150, plane=(0.0, 0.0, 10.0), seed: int = 0,
               blur_sigma: float = 1.0):
    """A rectified pair of a textured plane and its left ground-truth disparity.

    Args:
        width, height: image size in pixels.
        plane: ``(a, b, c)`` of ``d = a*u + b*v + c`` (left pixels); ``a < 1``.
        seed: texture seed.
        blur_sigma: texture smoothness (Gaussian sigma in pixels).

    Returns:
        ``(left, right, disp)``: uint8 (H, W) images and float32 (H, W) left
        disparity, NaN where the matching right column is outside the image.
    """
    a, b, c = (float(x) for x in plane)
    if a >= 1.0:
        raise CanopyStereoError(f"plane slope a must be < 1, got {a}")
    u = np.arange(width, dtype=np.float32)[None, :]
    v = np.arange(height, dtype=np.float32)[:, None]
    disp = (a * u + b * v + c).astype(np.float32) * np.ones((height, 1), np.float32)
    margin = int(np.ceil(max(abs(disp).max(), 1.0))) + 4
    tex = random_texture(width, height, seed, blur_sigma, margin)
    left = tex[:, margin:margin + width]
    # right column x sees left column (x + b*v + c) / (1 - a)
    x = np.arange(width, dtype=np.float32)[None, :]
    src_u = ((x + b * v + c) / (1.0 - a)).astype(np.float32) + margin
    src_v = np.repeat(v, width, axis=1).astype(np.float32)
    right = cv2.remap(tex, src_u, src_v, interpolation=cv2.INTER_CUBIC,
                      borderMode=cv2.BORDER_REFLECT)
    out_l = np.clip(np.rint(left), 0, 255).astype(np.uint8)
    out_r = np.clip(np.rint(right), 0, 255).astype(np.uint8)
    gt = disp.copy()
    gt[(u - disp) < 0] = np.nan
    return out_l, out_r, gt


def shifted_pair(width: int = 200, height: int = 150, shift: float = 10.0, seed: int = 0,
                 blur_sigma: float = 1.0):
    """A pair with the constant disparity ``shift`` (a fronto-parallel plane)."""
    return plane_pair(width, height, (0.0, 0.0, shift), seed, blur_sigma)
