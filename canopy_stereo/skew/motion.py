"""One camera's image motion between consecutive frames, and moving an image along it in time.

Pure core (numpy/OpenCV in and out, no ROS). The motion is dense optical flow
(OpenCV's DIS, Kroeger et al. ECCV 2016) from the *current* frame back to the
*previous* frame of the same camera, computed on grey images at a reduced
resolution (``scale``) and scaled up. It holds everything that moved in that
camera's view: the rig's own motion (with the parallax of near and far
things) and leaves moving in wind.

Moving an image by ``s`` frame intervals in time (``s < 0``: towards the
previous frame, ``s > 0``: beyond the current one) samples the current frame
at ``x + s * flow(x)``: a point that moves with constant velocity ``u``
pixels per frame and is at ``x`` at the wanted instant is at ``x - s u`` in the
current frame, and ``flow = -u``. The error of evaluating the flow at ``x``
rather than at the point's origin is second order in ``s u``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Grey-level gradient (DN per pixel, on the reduced image) a pixel needs to count as textured.
TEXTURE_GRADIENT_DN = 6.0
#: Grey-level residual (DN) below which the flow explains a textured pixel.
EXPLAINED_RESIDUAL_DN = 14.0


@dataclass
class ImageMotion:
    """Dense motion of one camera from its current frame back to its previous one.

    Attributes:
        flow_reduced: (h, w, 2) float32 flow at the reduced resolution, in reduced pixels:
            the current pixel ``x`` showed in the previous frame at ``x + flow(x)``.
        size: ``(W, H)`` of the full-resolution images.
        textured: fraction of pixels with a grey gradient of at least
            :data:`TEXTURE_GRADIENT_DN` (on the reduced image).
        explained: fraction of the textured pixels that the previous frame, moved along
            the flow, reproduces within :data:`EXPLAINED_RESIDUAL_DN` (after removing the
            mean brightness difference): near 1 for motion, low for a cut.
        median_px: median flow length (full-resolution pixels per frame interval).
    """

    flow_reduced: np.ndarray
    size: tuple[int, int]
    textured: float
    explained: float
    median_px: float

    def flow(self, factor: float = 1.0) -> np.ndarray:
        """(H, W, 2) float32 full-resolution flow in pixels, times ``factor``."""
        w, h = self.size
        sh, sw = self.flow_reduced.shape[:2]
        scaled = self.flow_reduced * np.float32(factor * w / sw)  # square pixels: one ratio
        if (sw, sh) == (w, h):
            return scaled
        return cv2.resize(scaled, (w, h), interpolation=cv2.INTER_LINEAR)


def _grey(image: np.ndarray, scale: float) -> np.ndarray:
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    if scale != 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(grey, dtype=np.uint8)


_DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
                "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
_dis_cache: dict = {}
_grid_cache: dict = {}


def _pixel_grid(width: int, height: int) -> np.ndarray:
    """float32 (H, W, 2) column and row of every pixel (cached per size, read-only)."""
    key = (width, height)
    if key not in _grid_cache:
        if len(_grid_cache) > 4:
            _grid_cache.clear()
        gx, gy = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
        grid = np.ascontiguousarray(np.stack([gx, gy], axis=-1))
        grid.flags.writeable = False
        _grid_cache[key] = grid
    return _grid_cache[key]


def _dis(preset: str):
    if preset not in _DIS_PRESETS:
        raise CanopyStereoError(f"unknown flow preset {preset!r}; choose one of {', '.join(_DIS_PRESETS)}")
    key = preset
    if key not in _dis_cache:  # one instance per preset and process: calc() reuses its buffers
        _dis_cache[key] = cv2.DISOpticalFlow.create(_DIS_PRESETS[preset])
    return _dis_cache[key]


def image_motion(previous: np.ndarray, current: np.ndarray, *, scale: float = 0.5,
                 preset: str = "fast") -> ImageMotion:
    """Dense motion from ``current`` back to ``previous`` (two frames of one camera).

    Args:
        previous, current: uint8 images (H, W) grey or (H, W, 3) BGR of one size.
        scale: resolution of the flow computation (0.5: half size; the flow is scaled
            back to full resolution).
        preset: DIS preset, ``ultrafast``, ``fast`` (default: a few ms per VGA pair, within
            1 % depth on the croton at 0.5 m/s with 16 ms skew) or ``medium`` (finer, several
            times slower); see ``benchmarks/bench_capture.py``.

    Returns an :class:`ImageMotion`.
    """
    if previous.shape != current.shape:
        raise CanopyStereoError(f"previous frame is {previous.shape[1]}x{previous.shape[0]} but the current "
                                f"one {current.shape[1]}x{current.shape[0]}")
    if not 0 < scale <= 1:
        raise CanopyStereoError(f"flow scale must be in (0, 1], got {scale}")
    h, w = current.shape[:2]
    if current.dtype != np.uint8 or previous.dtype != np.uint8:
        raise CanopyStereoError(f"frames must be uint8, got {previous.dtype} and {current.dtype}")
    prev_g, cur_g = _grey(previous, scale), _grey(current, scale)
    small = _dis(preset).calc(cur_g, prev_g, None)  # cur(x) ~ prev(x + small(x))
    # how well the motion explains the current frame, on the textured pixels
    sh, sw = cur_g.shape
    gx = cv2.Sobel(cur_g, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(cur_g, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    textured_px = cv2.magnitude(gx, gy) >= TEXTURE_GRADIENT_DN
    textured = float(textured_px.mean())
    predicted = _remap(prev_g, cv2.add(_pixel_grid(sw, sh), small))
    residual = cv2.absdiff(predicted, cur_g).astype(np.float32)
    offset = abs(float(predicted.mean()) - float(cur_g.mean()))  # a brightness change is not a cut
    explained = float((residual[textured_px] < EXPLAINED_RESIDUAL_DN + offset).mean()) if textured_px.any() else 0.0
    median_px = float(np.median(np.hypot(small[::2, ::2, 0], small[::2, ::2, 1]))) * (w / sw)
    return ImageMotion(flow_reduced=small, size=(w, h), textured=textured, explained=explained,
                       median_px=median_px)


def _remap(image: np.ndarray, coords: np.ndarray) -> np.ndarray:
    """``image`` sampled at ``coords`` (H, W, 2) float32 (bilinear, edges replicated); the
    maps go fixed-point first (1/32 pixel), several times faster than float maps."""
    map_xy, map_frac = cv2.convertMaps(coords, None, cv2.CV_16SC2)
    return cv2.remap(image, map_xy, map_frac, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def move_in_time(current: np.ndarray, motion: ImageMotion, frames: float) -> np.ndarray:
    """``current`` moved ``frames`` frame intervals in time along ``motion`` (current ->
    previous, :func:`image_motion`): negative towards the previous frame. Same shape and
    dtype as ``current``; bilinear, edges replicated."""
    h, w = current.shape[:2]
    if motion.size != (w, h):
        raise CanopyStereoError(f"the motion is of {motion.size[0]}x{motion.size[1]} images but the image "
                                f"is {w}x{h}")
    # the pixel x of the moved image is the current frame's x + frames * flow(x)
    return _remap(current, cv2.add(_pixel_grid(w, h), motion.flow(frames)))
