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

import math
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


def reduced_grey(image: np.ndarray, *, scale: float) -> np.ndarray:
    """uint8 (h, w) grey of a uint8 grey or BGR ``image`` at ``scale`` (area-averaged): what
    :func:`reduced_motion` takes (compute it once per frame and keep it for the next pair).
    A power of 1/2 is reached by halving (2x2 means, OpenCV's fast path) as often as needed."""
    grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
    while scale <= 0.5 and math.log2(scale).is_integer():
        grey = cv2.resize(grey, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        scale *= 2.0
    if scale != 1.0:
        grey = cv2.resize(grey, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(grey, dtype=np.uint8)


_DIS_PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST, "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
                "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}
_dis_cache: dict = {}
_grid_cache: dict = {}
_points_cache: dict = {}


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
                 preset: str = "ultrafast") -> ImageMotion:
    """Dense motion from ``current`` back to ``previous`` (two frames of one camera).

    Args:
        previous, current: uint8 images (H, W) grey or (H, W, 3) BGR of one size.
        scale: resolution of the flow computation (0.5: half size; the flow is scaled
            back to full resolution).
        preset: DIS preset, ``ultrafast`` (default: under 1 ms per VGA pair at half size,
            within 1 % depth on the croton at 0.5 m/s with 16 ms skew), ``fast`` (about twice
            the time, no more accurate there) or ``medium`` (finer, several times slower); see
            ``benchmarks/bench_capture.py``.

    Returns an :class:`ImageMotion`.
    """
    check_frames(previous, current, scale=scale)
    h, w = current.shape[:2]
    return reduced_motion(reduced_grey(previous, scale=scale), reduced_grey(current, scale=scale), size=(w, h),
                          preset=preset)


def check_frames(previous: np.ndarray, current: np.ndarray, *, scale: float) -> None:
    """:class:`CanopyStereoError` naming the problem unless ``previous`` and ``current`` are
    uint8 frames of one size and ``scale`` is in (0, 1]."""
    if previous.shape[:2] != current.shape[:2]:
        raise CanopyStereoError(f"previous frame is {previous.shape[1]}x{previous.shape[0]} but the current "
                                f"one {current.shape[1]}x{current.shape[0]}")
    if not 0 < scale <= 1:
        raise CanopyStereoError(f"flow scale must be in (0, 1], got {scale}")
    if current.dtype != np.uint8 or previous.dtype != np.uint8:
        raise CanopyStereoError(f"frames must be uint8, got {previous.dtype} and {current.dtype}")


def reduced_motion(previous: np.ndarray, current: np.ndarray, *, size: tuple[int, int],
                   preset: str = "ultrafast") -> ImageMotion:
    """:func:`image_motion` of two frames already reduced by :func:`reduced_grey` (uint8 (h, w)
    each, one scale); ``size``: ``(W, H)`` of the full-resolution frames."""
    w, h = size
    prev_g, cur_g = previous, current
    if prev_g.shape != cur_g.shape:
        raise CanopyStereoError(f"reduced frames of {prev_g.shape} and {cur_g.shape}: reduce both at one scale")
    small = _dis(preset).calc(cur_g, prev_g, None)  # cur(x) ~ prev(x + small(x))
    # how well the motion explains the current frame, on the textured pixels
    sh, sw = cur_g.shape
    gx = cv2.Sobel(cur_g, cv2.CV_32F, 1, 0, ksize=3, scale=0.125)
    gy = cv2.Sobel(cur_g, cv2.CV_32F, 0, 1, ksize=3, scale=0.125)
    textured_px = cv2.compare(cv2.magnitude(gx, gy), TEXTURE_GRADIENT_DN, cv2.CMP_GE)  # 255 where textured
    n_textured = cv2.countNonZero(textured_px)
    textured = n_textured / textured_px.size
    predicted = _remap(prev_g, cv2.add(_pixel_grid(sw, sh), small))
    residual = cv2.absdiff(predicted, cur_g)
    offset = abs(cv2.mean(predicted)[0] - cv2.mean(cur_g)[0])  # a brightness change is not a cut
    # residual < limit on whole grey levels: residual < ceil(limit)
    limit = math.ceil(EXPLAINED_RESIDUAL_DN + offset)
    explained = 0.0
    if n_textured:
        below = cv2.compare(residual, limit, cv2.CMP_LT) if limit <= 255 else np.full_like(residual, 255)
        explained = cv2.countNonZero(cv2.bitwise_and(below, textured_px)) / n_textured
    return ImageMotion(flow_reduced=small, size=(w, h), textured=textured, explained=explained,
                       median_px=flow_percentile_px(small, size=(w, h), percentile=50.0))


def flow_percentile_px(flow_reduced: np.ndarray, *, size: tuple[int, int], percentile: float) -> float:
    """``percentile`` (0-100) of the flow's length over a grid of every 4th reduced pixel, in
    full-resolution pixels per frame interval (``size``: ``(W, H)`` of the full frames)."""
    sample = np.ascontiguousarray(flow_reduced[::4, ::4])
    lengths = cv2.magnitude(sample[..., 0], sample[..., 1])
    return float(np.percentile(lengths, percentile)) * (size[0] / flow_reduced.shape[1])


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



def sample_moved(image: np.ndarray, motion: ImageMotion, frames: float, *, coords: np.ndarray) -> np.ndarray:
    """``image`` moved ``frames`` frame intervals in time along ``motion`` (as
    :func:`move_in_time`) and sampled at ``coords``, in one interpolation:
    ``out(p) = image(c + frames * flow(c))`` with ``c = coords(p)``.

    ``coords``: (H', W', 2) float32 column and row in ``image`` (full-resolution pixels) of each
    output pixel, e.g. a rectification map (:meth:`~canopy_stereo.geometry.rectification.StereoRectifier.coordinates`):
    the skew shift is composed into it instead of warping the image first. Returns an image of
    ``image``'s dtype and channels, (H', W'); bilinear; pixels sampled outside the image are 0
    (as rectification's). The flow at ``c`` is evaluated on the output grid at the flow's
    resolution and upsampled bilinearly (the flow has no finer detail).
    """
    w, h = motion.size
    if image.shape[:2] != (h, w):
        raise CanopyStereoError(f"the motion is of {w}x{h} images but the image is "
                                f"{image.shape[1]}x{image.shape[0]}")
    if coords.ndim != 3 or coords.shape[2] != 2 or coords.dtype != np.float32:
        raise CanopyStereoError(f"coords must be float32 (H, W, 2), got {coords.dtype} {coords.shape}")
    sh, sw = motion.flow_reduced.shape[:2]
    k = sw / w  # reduced pixels per full pixel (square pixels: one ratio)
    oh, ow = coords.shape[:2]
    grid = _output_grid(coords, k=k, size=(w, h), reduced=(sw, sh))
    flow_at = cv2.remap(motion.flow_reduced, grid.points, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    # composed on the coarse grid (flow in full pixels, times frames), then upsampled once: the
    # map is smooth, its bilinear upsampling its own positions (within 1/64 pixel, the fixed
    # map's step) but at the borders, where the upsampling clamps and the map's own are put back
    moved = cv2.resize(cv2.scaleAdd(flow_at, float(frames) / k, grid.coarse), (ow, oh),
                       interpolation=cv2.INTER_LINEAR)
    grid.restore_borders(moved)
    # float maps as they are: converting them to fixed point per frame costs what it saves
    return cv2.remap(image, moved, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


@dataclass(frozen=True)
class _OutputGrid:
    """A coordinate map (H', W', 2) on the output grid at the flow's resolution (h', w').

    Attributes:
        coarse: float32 (h', w', 2) the map there, in full-resolution pixels (sample centres:
            output pixel ``(u + 0.5) W' / w' - 0.5``).
        points: float32 (h', w', 2) the same positions in reduced pixels
            (``u_reduced = (u + 0.5) k - 0.5``): where the flow is read.
        band: border width (output pixels) where upsampling ``coarse`` clamps.
        top, bottom, left, right: float32 corrections ``map - upsampled coarse`` on the border
            bands (rows: the full width; columns: between the row bands).
    """

    coarse: np.ndarray
    points: np.ndarray
    band: int
    top: np.ndarray
    bottom: np.ndarray
    left: np.ndarray
    right: np.ndarray

    def restore_borders(self, moved: np.ndarray) -> None:
        """Add the border corrections to ``moved`` (H', W', 2), an upsampled coarse map, in place."""
        b = self.band
        moved[:b] += self.top
        moved[-b:] += self.bottom
        moved[b:-b, :b] += self.left
        moved[b:-b, -b:] += self.right


def _output_grid(coords: np.ndarray, *, k: float, size: tuple[int, int], reduced: tuple[int, int]) -> _OutputGrid:
    """The :class:`_OutputGrid` of ``coords`` (H', W', 2) for a flow ``reduced`` ``(w, h)`` of
    images ``size`` ``(W, H)``, ``k`` reduced pixels per pixel; kept per coordinate map (a
    rectifier's, read-only: the same every frame)."""
    key = (id(coords), coords.shape, k, size, reduced)
    hit = _points_cache.get(key)
    if hit is not None and hit[0] is coords and not coords.flags.writeable:
        return hit[1]
    w, h = size
    sw, sh = reduced
    oh, ow = coords.shape[:2]
    small = (max(1, round(ow * sw / w)), max(1, round(oh * sh / h)))
    coarse = cv2.resize(coords, small, interpolation=cv2.INTER_LINEAR)
    band = min(int(math.ceil(max(ow / small[0], oh / small[1]))) + 1, min(ow, oh) // 2)
    missing = coords - cv2.resize(coarse, (ow, oh), interpolation=cv2.INTER_LINEAR)
    grid = _OutputGrid(coarse=coarse, points=coarse * np.float32(k) + np.float32(0.5 * k - 0.5), band=band,
                       top=missing[:band].copy(), bottom=missing[-band:].copy(),
                       left=missing[band:-band, :band].copy(), right=missing[band:-band, -band:].copy())
    if not coords.flags.writeable:  # a fixed map: keep it (and the map, so that its id stays its own)
        if len(_points_cache) > 4:
            _points_cache.clear()
        _points_cache[key] = (coords, grid)
    return grid
