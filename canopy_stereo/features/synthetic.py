"""Generated stereo pairs with known correspondences, for checking matchers.

:func:`slanted_plane_pair` gives a textured left image and the right image a
rectified camera sees of the same slanted plane: left pixel ``(u, v)`` appears at
``(u - d(u, v), v)`` with ``d = d0 + gu u + gv v`` pixels. Nothing is read from disk.
"""
from __future__ import annotations

import cv2
import numpy as np


def textured_image(width: int, height: int, seed: int = 1, scale: float = 1.0) -> np.ndarray:
    """uint8 (H, W) band-limited noise at two scales (fine: sigma 1.2 ``scale`` px,
    coarse: 4 ``scale`` px)."""
    rng = np.random.default_rng(seed)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (height, width)), (0, 0), 1.2 * scale)
    coarse = cv2.GaussianBlur(rng.normal(0, 1, (height, width)), (0, 0), 4.0 * scale)
    img = 0.6 * fine / fine.std() + 0.8 * coarse / coarse.std()
    return np.clip(128 + 40 * img, 0, 255).astype(np.uint8)


def slanted_plane_pair(width: int = 240, height: int = 180, d0: float = 9.0, gu: float = 0.03,
                       gv: float = 0.02, noise: float = 1.5, seed: int = 1,
                       texture_scale: float = 1.0):
    """``(left, right, disparity)`` of a textured slanted plane seen by a rectified rig.

    Args:
        width, height: image size in pixels.
        d0, gu, gv: disparity ``d(u, v) = d0 + gu u + gv v`` in pixels (``gu < 1``).
        noise: standard deviation of the Gaussian noise added to each image (grey levels).
        seed: random seed of the texture and the noise.
        texture_scale: blur scale of the texture (larger: smoother, fewer keypoints).

    Returns:
        uint8 (H, W) left and right images and the float64 (H, W) left disparity.
    """
    left = textured_image(width, height, seed, texture_scale)
    u = np.arange(width, dtype=np.float64)[None, :]
    v = np.arange(height, dtype=np.float64)[:, None]
    disparity = d0 + gu * u + gv * v
    # right pixel u' shows the left point u with u - d(u, v) = u', i.e. u = (u' + d0 + gv v) / (1 - gu)
    map_x = np.broadcast_to((u + d0 + gv * v) / (1.0 - gu), (height, width)).astype(np.float32)
    map_y = np.broadcast_to(v, (height, width)).astype(np.float32)
    right = cv2.remap(left, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    rng = np.random.default_rng(seed + 1000)

    def noisy(img):
        return np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)

    return noisy(left), noisy(right), disparity
