"""Plant masks for video: the plant model propagated from frame to frame (GrabCut at camera rate).

A full GrabCut (the one seeder, :func:`canopy_stereo.segmentation.plant_mask` with the
video preset :data:`~canopy_stereo.segmentation.VIDEO_SEEDER` or any :class:`SeederSettings`:
a seed, then
colour models learned by k-means and three iterations of model fitting and graph cuts,
at the node's ``scale``) costs about 18 ms of CPU per 640x480 frame, a quarter of what a
2-core machine has per frame at 30 frames/s. From one video frame to the next the plant
and its background keep their colours, so the colour models (the plant model) need not
be learned again. :class:`MaskPropagator` therefore

* makes a **full cut** (``plant_mask``, the reference) on the first frame, every
  ``recut_every`` frames, and whenever the propagated mask looks lost (empty, or its area
  changed by more than :data:`MAX_AREA_CHANGE` since the last full cut); then it fits the
  plant and background colour models to that mask
  (:func:`~canopy_stereo.segmentation.colour_model.fit_colour_gmm`, :data:`MODEL_SAMPLES`
  pixels each);
* **propagates** on the other frames: the frame's own seed (the same rectangle or
  automatic initialisation as the full cut, with the frame's disparity when the seeder has
  a depth cue: its sure pixels follow the plant as it moves)
  and one graph cut with the propagated models kept fixed
  (:func:`~canopy_stereo.segmentation.colour_model.grabcut_with_models`, OpenCV's
  ``GC_EVAL_FREEZE_MODEL`` energy solved on the seed's undecided pixels only,
  :mod:`~canopy_stereo.segmentation.frozen_cut`), at ``propagate_scale`` (default: the full
  cut's ``scale``; lower is cheaper and coarser).

Measured (``test/test_segmentation_propagate.py``; ``benchmarks/bench_graph.py``,
``segment`` row): on the bundled scenes the propagated masks stay within IoU 0.95 of a
full GrabCut of the same frame (croton, 4 frames of breeze: >= 0.98; the real Plants pair
with sensor noise: >= 0.97; the Plants crop drifting 1.3 px a frame: 0.98 on average,
0.93 at worst; a rectangle seed, which says nothing about colours, 0.88). CPU per 640x480
frame (``benchmarks/bench_segmentation.py --video``, loaded): about 2-3 ms on propagated frames,
4-5 ms on average with ``recut_every`` 10 (a full cut and the model fits cost about 19-21 ms);
every graph cut is solved on the seed's undecided pixels only
(:mod:`~canopy_stereo.segmentation.frozen_cut`).

At HD the same ``scale`` would cut 4 to 9 times as many pixels; ``max_pixels`` caps the
processing resolution instead (:func:`capped_scale`): the node's default, :data:`DEFAULT_MAX_PIXELS`,
is a 640x480 frame at the video preset's quarter scale, so a 1280x720 frame is segmented at
about 184x104 pixels and its mask upsampled, at the CPU cost of a 640x480 frame.

Masks are uint8 (H, W), 255 = plant, in the pixels of the images given.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.segmentation.auto import AUTO_INITS, VIDEO_SEEDER, SeederSettings, plant_mask, seed_labels
from canopy_stereo.segmentation.colour_model import MIN_SAMPLES, fit_colour_gmm, grabcut_with_models
from canopy_stereo.segmentation.grabcut import labels_to_mask

#: Default frames between two full cuts (1 = every frame is a full cut: no propagation).
DEFAULT_RECUT_EVERY = 10
#: Pixels drawn for each colour model after a full cut (few: the fit runs in the frame's time).
MODEL_SAMPLES = 2000
#: EM iterations of those fits.
MODEL_ITERATIONS = 3
#: Pixels GrabCut works on at most in the nodes (``max_pixels``): a 640x480 frame at the video
#: preset's quarter scale; larger frames are segmented at a lower scale.
DEFAULT_MAX_PIXELS = 160 * 120
#: Relative change of the plant's area since the last full cut beyond which the frame is cut
#: in full again (the plant left, a hand came in, the light changed).
MAX_AREA_CHANGE = 0.3


def capped_scale(scale: float, image_size, *, max_pixels: int) -> float:
    """``scale`` lowered so that an image of ``image_size`` ``(width, height)`` is processed at
    no more than ``max_pixels`` pixels (``max_pixels <= 0``: ``scale`` unchanged)."""
    w, h = (int(v) for v in image_size)
    if int(max_pixels) <= 0 or w * h * scale * scale <= int(max_pixels):
        return float(scale)
    return float(np.sqrt(int(max_pixels) / float(w * h)))


def frame_seed(small_bgr: np.ndarray, rect_small, auto_init: str) -> np.ndarray:
    """GrabCut seed labels of one (already downscaled) frame: the video seeder's own
    initialisation (a rectangle, or the automatic seed ``auto_init``) at that frame's size."""
    return seed_labels(small_bgr, VIDEO_SEEDER.replace(colour_cue=auto_init, scale=1.0), rect=rect_small)


class MaskPropagator:
    """Plant masks of consecutive video frames (see the module docstring).

    Keyword args:
        rect, iterations, auto_init, scale: the full cut's settings (:func:`segment_plant`),
            when no ``settings`` are given.
        settings: the seeder's :class:`SeederSettings` (e.g. ``VIDEO_SEEDER`` with
            ``depth_cue``); overrides ``iterations``, ``auto_init`` and ``scale``.
        recut_every: frames between two full cuts (>= 1; 1 = every frame in full).
        propagate_scale: processing scale of the propagated frames in (0, 1] (default: ``scale``).
        max_pixels: both scales are lowered for images larger than this many processed pixels
            (:func:`capped_scale`; 0 = no cap, the default).

    Attributes:
        full_cuts, propagated: frames segmented each way so far.
    """

    def __init__(self, *, rect=None, iterations: int = 3, auto_init: str = "saturation", scale: float = 0.25,
                 recut_every: int = DEFAULT_RECUT_EVERY, propagate_scale: float | None = None,
                 settings: SeederSettings | None = None, max_pixels: int = 0):
        if settings is None:
            if auto_init not in AUTO_INITS:
                raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}, got {auto_init!r}")
            settings = VIDEO_SEEDER.replace(colour_cue=auto_init, iterations=int(iterations), scale=float(scale))
        self.settings = settings
        iterations, auto_init, scale = settings.iterations, settings.colour_cue, settings.scale
        propagate_scale = scale if propagate_scale is None else propagate_scale
        if int(recut_every) < 1:
            raise CanopyStereoError(f"recut_every must be >= 1, got {recut_every}")
        if not 0 < propagate_scale <= 1:
            raise CanopyStereoError(f"propagate_scale must be in (0, 1], got {propagate_scale}")
        self.max_pixels = int(max_pixels)
        self._base = (settings, float(propagate_scale))  # the scales before any cap
        self._size: tuple[int, int] | None = None
        self.rect = None if rect is None else tuple(int(v) for v in rect)
        self.iterations, self.auto_init, self.scale = int(iterations), auto_init, float(scale)
        self.recut_every = int(recut_every)
        self.propagate_scale = float(propagate_scale)
        self._seed_settings = settings.replace(scale=self.propagate_scale, colour_model=False)
        self._small_seed_settings = self._seed_settings.replace(scale=1.0)
        self.full_cuts = 0
        self.propagated = 0
        self.reset()

    def reset(self) -> None:
        """Forget the models: the next frame is cut in full."""
        self._models: tuple | None = None  # (plant, background) ColourGMM
        self._since_full = 0
        self._full_area = 0.0  # plant share of the image at the last full cut

    def segment(self, bgr: np.ndarray, disparity: np.ndarray | None = None) -> np.ndarray:
        """Plant mask of the next frame: uint8 (H, W), 255 = plant (``disparity``: the frame's
        (H, W) disparity, pixels, high = near, NaN/negative = unknown, for a seeder with
        ``depth_cue``)."""
        if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
            raise ImageError(f"segmentation needs a uint8 BGR image, got {bgr.dtype} {bgr.shape}")
        h, w = bgr.shape[:2]
        if self.max_pixels > 0 and self._size != (w, h):
            self._cap((w, h))
        small = bgr if self.propagate_scale == 1 else cv2.resize(
            bgr, (max(8, round(w * self.propagate_scale)), max(8, round(h * self.propagate_scale))),
            interpolation=cv2.INTER_AREA)
        if self._models is None or self._since_full >= self.recut_every:
            return self._full(bgr, small, disparity)
        # the frame's own seed at propagate_scale (the models are the propagated ones: none learned)
        if disparity is None and self.rect is None:  # the same seed from the frame already downscaled
            seed = seed_labels(small, self._small_seed_settings)
        else:
            seed = seed_labels(bgr, self._seed_settings, disparity=disparity, rect=self.rect)
        plant = labels_to_mask(grabcut_with_models(small, seed, *self._models))
        share = float(np.count_nonzero(plant)) / plant.size
        if share == 0 or abs(share - self._full_area) > MAX_AREA_CHANGE * self._full_area:
            return self._full(bgr, small, disparity)
        self._since_full += 1
        self.propagated += 1
        if plant.shape != (h, w):
            plant = cv2.resize(plant, (w, h), interpolation=cv2.INTER_LINEAR)
            cv2.threshold(plant, 127, 255, cv2.THRESH_BINARY, dst=plant)  # in place: >= 128: 255, else 0
        return plant

    __call__ = segment

    def _cap(self, size: tuple[int, int]) -> None:
        """The scales for images of ``size``: the given ones, capped to ``max_pixels``; a new
        size starts again with a full cut."""
        settings, propagate_scale = self._base
        self.settings = settings.replace(scale=capped_scale(settings.scale, size, max_pixels=self.max_pixels))
        self.scale = self.settings.scale
        self.propagate_scale = capped_scale(propagate_scale, size, max_pixels=self.max_pixels)
        self._seed_settings = self.settings.replace(scale=self.propagate_scale, colour_model=False)
        self._small_seed_settings = self._seed_settings.replace(scale=1.0)
        self._size = size
        self.reset()

    def _full(self, bgr: np.ndarray, small: np.ndarray, disparity) -> np.ndarray:
        mask = plant_mask(bgr, self.settings, disparity=disparity, rect=self.rect)
        self.full_cuts += 1
        self._since_full = 1
        inside = (cv2.resize(mask, small.shape[1::-1], interpolation=cv2.INTER_AREA) >= 128).reshape(-1)
        self._full_area = float(inside.mean())
        pixels = small.reshape(-1, 3)
        if MIN_SAMPLES <= inside.sum() <= inside.size - MIN_SAMPLES:
            self._models = tuple(fit_colour_gmm(pixels[side], max_samples=MODEL_SAMPLES,
                                                iterations=MODEL_ITERATIONS) for side in (inside, ~inside))
        else:  # (almost) no plant or no background: nothing to learn, cut in full next time too
            self._models = None
        return mask
