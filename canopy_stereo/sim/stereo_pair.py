"""The package's one generator of synthetic rectified stereo pairs with exactly known
disparity (tests, demos, kernel warm-up).

The scene is a textured plane ``d(u, v) = a*u + b*v + c`` seen by the left camera:
the left image samples a random texture ``T`` at ``(u, v)``; the right image at
column ``x`` shows the scene point whose left column ``u`` satisfies
``x = u - d(u, v)``, i.e. ``u = (x + b*v + c) / (1 - a)``. Sampling uses bicubic
interpolation of ``T``, so sub-pixel disparities are rendered faithfully (and an
integer constant disparity is an exact shift).

:func:`synthetic_pair` is the generator; its textures (:data:`TEXTURES`):

* ``smooth``: uniform noise blurred by ``blur_sigma`` pixels, stretched to 0..255 and
  sampled in floating point (the ELAS tests' pairs: :func:`plane_pair`, :func:`shifted_pair`);
* ``two_scale``: band-limited noise at two scales (sigma 1.2 and 4 ``texture_scale``
  pixels) on uint8, plus Gaussian noise per image (the feature matchers' pairs:
  :func:`slanted_plane_pair`);
* ``blocks``: uniform random grey levels (or colours) in 2x2 blocks, linearly
  interpolated (the ROS node tests' pairs).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Texture kinds of :func:`synthetic_pair`.
TEXTURES = ("smooth", "two_scale", "blocks")


def random_texture(width: int, height: int, *, seed: int = 0, blur_sigma: float = 1.0,
                   margin: int = 0) -> np.ndarray:
    """float32 (height, width + 2*margin) smooth random texture in 0..255."""
    rng = np.random.default_rng(seed)
    noise = rng.uniform(0.0, 1.0, size=(height, width + 2 * margin)).astype(np.float32)
    tex = cv2.GaussianBlur(noise, (0, 0), blur_sigma) if blur_sigma > 0 else noise
    tex -= tex.min()
    tex *= 255.0 / max(float(tex.max()), 1e-6)
    return tex


def textured_image(width: int, height: int, *, seed: int = 1, scale: float = 1.0) -> np.ndarray:
    """uint8 (H, W) band-limited noise at two scales (fine: sigma 1.2 ``scale`` px,
    coarse: 4 ``scale`` px)."""
    rng = np.random.default_rng(seed)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (height, width)), (0, 0), 1.2 * scale)
    coarse = cv2.GaussianBlur(rng.normal(0, 1, (height, width)), (0, 0), 4.0 * scale)
    img = 0.6 * fine / fine.std() + 0.8 * coarse / coarse.std()
    return np.clip(128 + 40 * img, 0, 255).astype(np.uint8)


def _block_texture(width: int, height: int, *, seed: int, colour: bool) -> np.ndarray:
    """uint8 (height, width[, 3]) uniform random levels in 2x2 blocks, linearly interpolated."""
    rng = np.random.default_rng(seed)
    shape = (height // 2 + 1, width // 2 + 1) + ((3,) if colour else ())
    tex = cv2.resize(rng.integers(0, 256, shape, dtype=np.uint8), None, fx=2, fy=2,
                     interpolation=cv2.INTER_LINEAR)
    return tex[:height, :width]


def synthetic_pair(width: int = 200, height: int = 150, *, plane=(0.0, 0.0, 10.0), texture: str = "smooth",
                   seed: int = 0, blur_sigma: float = 1.0, texture_scale: float = 1.0, colour: bool = False,
                   noise: float = 0.0, outside: float | None = np.nan):
    """A rectified pair of a textured plane and its left ground-truth disparity.

    Args:
        width, height: image size in pixels.
        plane: ``(a, b, c)`` of ``d = a*u + b*v + c`` (left pixels); ``a < 1``. The
            ``blocks`` texture takes a constant integer disparity only (``a = b = 0``).
        texture: ``"smooth"``, ``"two_scale"`` or ``"blocks"`` (see the module docstring).
        seed: texture (and noise) seed.
        blur_sigma: smoothness of the ``smooth`` texture (Gaussian sigma in pixels).
        texture_scale: blur scale of the ``two_scale`` texture (larger: smoother, fewer keypoints).
        colour: BGR (H, W, 3) images (``blocks`` only) instead of grey (H, W).
        noise: standard deviation of Gaussian noise added to each image (grey levels;
            drawn from ``seed + 1000``).
        outside: disparity written where the right match falls left of the right image
            (default NaN); None keeps the plane's value.

    Returns:
        ``(left, right, disparity)``: uint8 images and the left disparity (pixels):
        float32 (H, W), or float64 for ``two_scale``.
    """
    a, b, c = (float(x) for x in plane)
    if a >= 1.0:
        raise CanopyStereoError(f"plane slope a must be < 1, got {a}")
    if texture not in TEXTURES:
        raise CanopyStereoError(f"unknown texture {texture!r}; choose one of {', '.join(TEXTURES)}")
    if colour and texture != "blocks":
        raise CanopyStereoError("colour pairs are made with the blocks texture")
    if texture == "two_scale":
        u = np.arange(width, dtype=np.float64)[None, :]
        v = np.arange(height, dtype=np.float64)[:, None]
        disp = np.broadcast_to(c + a * u + b * v, (height, width)).copy()
        left = textured_image(width, height, seed=seed, scale=texture_scale)
        # right pixel x shows the left point u with u - d(u, v) = x, i.e. u = (x + c + b v) / (1 - a)
        map_x = np.broadcast_to((u + c + b * v) / (1.0 - a), (height, width)).astype(np.float32)
        map_y = np.broadcast_to(v, (height, width)).astype(np.float32)
        right = cv2.remap(left, map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    elif texture == "blocks":
        if a != 0 or b != 0 or c != round(c) or c < 0:
            raise CanopyStereoError(f"the blocks texture takes a constant integer disparity >= 0, got {plane}")
        shift = int(c)
        tex = _block_texture(width + shift, height, seed=seed, colour=colour)
        left, right = tex[:, :width].copy(), tex[:, shift:shift + width].copy()
        disp = np.full((height, width), c, np.float32)
        u = np.arange(width, dtype=np.float32)[None, :]
    else:
        u = np.arange(width, dtype=np.float32)[None, :]
        v = np.arange(height, dtype=np.float32)[:, None]
        disp = (a * u + b * v + c).astype(np.float32) * np.ones((height, 1), np.float32)
        margin = int(np.ceil(max(abs(disp).max(), 1.0))) + 4
        tex = random_texture(width, height, seed=seed, blur_sigma=blur_sigma, margin=margin)
        # right column x sees left column (x + b*v + c) / (1 - a)
        x = np.arange(width, dtype=np.float32)[None, :]
        src_u = ((x + b * v + c) / (1.0 - a)).astype(np.float32) + margin
        src_v = np.repeat(v, width, axis=1).astype(np.float32)
        right = cv2.remap(tex, src_u, src_v, interpolation=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        left = np.clip(np.rint(tex[:, margin:margin + width]), 0, 255).astype(np.uint8)
        right = np.clip(np.rint(right), 0, 255).astype(np.uint8)
    if noise > 0:
        rng = np.random.default_rng(seed + 1000)
        left, right = (np.clip(img + rng.normal(0, noise, img.shape), 0, 255).astype(np.uint8)
                       for img in (left, right))
    if outside is not None:
        disp[(u - disp) < 0] = outside
    return left, right, disp


def plane_pair(width: int = 200, height: int = 150, *, plane=(0.0, 0.0, 10.0), seed: int = 0,
               blur_sigma: float = 1.0):
    """:func:`synthetic_pair` with the ``smooth`` texture: uint8 (H, W) images and float32
    (H, W) left disparity, NaN where the matching right column is outside the image."""
    return synthetic_pair(width, height, plane=plane, seed=seed, blur_sigma=blur_sigma)


def shifted_pair(width: int = 200, height: int = 150, *, shift: float = 10.0, seed: int = 0,
                 blur_sigma: float = 1.0):
    """A pair with the constant disparity ``shift`` (a fronto-parallel plane; ``smooth`` texture)."""
    return plane_pair(width, height, plane=(0.0, 0.0, shift), seed=seed, blur_sigma=blur_sigma)


def slanted_plane_pair(width: int = 240, height: int = 180, *, d0: float = 9.0, gu: float = 0.03,
                       gv: float = 0.02, noise: float = 1.5, seed: int = 1, texture_scale: float = 1.0):
    """``(left, right, disparity)`` of a textured slanted plane ``d(u, v) = d0 + gu u + gv v``
    pixels (``gu < 1``) seen by a rectified rig: :func:`synthetic_pair` with the ``two_scale``
    texture, ``noise`` grey levels of Gaussian noise per image, and the float64 (H, W) left
    disparity everywhere (also where the match leaves the right image)."""
    return synthetic_pair(width, height, plane=(gu, gv, d0), texture="two_scale", seed=seed,
                          texture_scale=texture_scale, noise=noise, outside=None)
