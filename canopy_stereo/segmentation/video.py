"""Fast GrabCut plant masks for video streams (used by the ROS ``segment_node``).

GrabCut is costly, so the frame is segmented at a reduced ``scale`` and the
mask resized back. The seed is the paper's rectangle, or an automatic one: an
index thresholded by Otsu's method with a band around the threshold left to
GrabCut to decide:

* ``saturation``: colourful plant in front of a neutral backdrop (laboratory);
* ``exg``: excess-green vegetation index (green canopies against soil or sky);
* ``border``: everything but a 5 % frame is probably plant.

For single images with a depth cue, :func:`canopy_stereo.segmentation.auto_plant_mask`
is more accurate (and slower).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.segmentation.grabcut import grabcut_labels, labels_to_mask
from canopy_stereo.segmentation.indices import excess_green


AUTO_INITS = ("saturation", "exg", "border")


def _initial_labels(bgr, rect, auto_init: str) -> np.ndarray:
    """GrabCut seed labels for a rectangle or an automatic initialisation."""
    h, w = bgr.shape[:2]
    labels = np.full((h, w), cv2.GC_BGD, np.uint8)
    if rect is not None:
        x, y, rw, rh = rect
        labels[y:y + rh, x:x + rw] = cv2.GC_PR_FGD
        return labels
    if auto_init == "border":
        mx, my = max(1, w // 20), max(1, h // 20)
        labels[my:h - my, mx:w - mx] = cv2.GC_PR_FGD
        return labels
    if auto_init == "saturation":
        index8 = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)[..., 1]
    else:
        index8 = np.clip((excess_green(bgr) + 1.0) * (255.0 / 3.0), 0, 255).astype(np.uint8)
    thr, _ = cv2.threshold(index8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    margin = 12  # index units around Otsu's threshold left to GrabCut to decide
    labels[index8 >= thr - margin] = cv2.GC_PR_BGD
    labels[index8 >= thr] = cv2.GC_PR_FGD
    labels[index8 >= thr + margin] = cv2.GC_FGD
    return labels


def segment_plant(bgr: np.ndarray, rect=None, iterations: int = 3, auto_init: str = "saturation",
                  scale: float = 0.25) -> np.ndarray:
    """Plant mask of a BGR image by GrabCut: uint8 (H, W), 255 = plant.

    Args:
        bgr: uint8 (H, W, 3) image.
        rect: ``(x, y, width, height)`` rectangle containing the plant (pixels of
            ``bgr``), or None for the automatic initialisation.
        iterations: GrabCut iterations (>= 1).
        auto_init: ``"saturation"``, ``"exg"`` or ``"border"`` (see the module docstring).
        scale: processing scale in (0, 1].
    """
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ImageError(f"segmentation needs a uint8 BGR image, got {bgr.dtype} {bgr.shape}")
    if not 0 < scale <= 1:
        raise CanopyStereoError(f"scale must be in (0, 1], got {scale}")
    if iterations < 1:
        raise CanopyStereoError(f"iterations must be >= 1, got {iterations}")
    if auto_init not in AUTO_INITS:
        raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}, got {auto_init!r}")
    h, w = bgr.shape[:2]
    small = bgr if scale == 1 else cv2.resize(bgr, (max(8, round(w * scale)), max(8, round(h * scale))),
                                              interpolation=cv2.INTER_AREA)
    sh, sw = small.shape[:2]
    srect = None
    if rect is not None:
        x, y, rw, rh = (int(v) for v in rect)
        x0, y0 = max(0, x), max(0, y)
        x1, y1 = min(w, x + rw), min(h, y + rh)
        if x1 - x0 < 2 or y1 - y0 < 2:
            raise CanopyStereoError(f"rectangle {list(rect)} does not overlap the {w}x{h} image")
        fx, fy = sw / w, sh / h
        srect = (int(x0 * fx), int(y0 * fy), max(2, int((x1 - x0) * fx)), max(2, int((y1 - y0) * fy)))
    labels = _initial_labels(small, srect, auto_init)
    if not np.any((labels == cv2.GC_FGD) | (labels == cv2.GC_PR_FGD)):
        return np.zeros((h, w), np.uint8)
    if not np.any((labels == cv2.GC_BGD) | (labels == cv2.GC_PR_BGD)):
        return np.full((h, w), 255, np.uint8)
    mask = labels_to_mask(grabcut_labels(small, labels, int(iterations)))
    if mask.shape != (h, w):
        mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_LINEAR)
        mask = np.where(mask >= 128, 255, 0).astype(np.uint8)
    return mask
