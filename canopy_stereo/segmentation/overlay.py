"""The overlay picture of a plant mask: its outline (and plant numbers) over the image."""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.images import to_bgr

#: BGR colours of the plants' outlines, cycled (the mask's outline without instances is the first).
OUTLINE_COLOURS = ((255, 0, 255), (0, 255, 255), (255, 255, 0), (0, 128, 255), (255, 64, 64), (64, 255, 64))


def mask_overlay(image_bgr, mask, *, instances=None, thickness: int = 2, label: bool = True) -> np.ndarray:
    """The image with the outline of ``mask`` drawn over it (uint8 BGR (H, W, 3), a copy).

    Args:
        image_bgr: (H, W, 3) uint8 BGR image (grey is accepted).
        mask: (H, W) plant mask (nonzero = plant).
        instances: optional (H, W) plant numbers (0 = none): each plant is outlined in
            its own colour and labelled with its number at its top.
        thickness: outline width in pixels (>= 1).
        label: write the plant numbers.
    """
    img = to_bgr(np.asarray(image_bgr), "image").copy()
    m = np.asarray(mask)
    if m.ndim == 3:
        m = m.max(axis=2)
    if m.shape != img.shape[:2]:
        raise ImageError(f"mask is {m.shape[1] if m.ndim > 1 else '?'}x{m.shape[0]} but the image is "
                         f"{img.shape[1]}x{img.shape[0]}")
    if thickness < 1:
        raise ImageError(f"outline thickness must be >= 1 pixel, got {thickness}")
    if instances is None:
        parts = [(1, m > 0)]
    else:
        inst = np.asarray(instances)
        if inst.shape != m.shape:
            raise ImageError(f"instances are {inst.shape} but the mask is {m.shape}")
        parts = [(int(k), inst == k) for k in np.unique(inst[inst > 0])]
    dim = (m == 0)
    img[dim] = (img[dim] * 0.6).astype(np.uint8)  # the plant stands out
    for k, region in parts:
        colour = OUTLINE_COLOURS[(k - 1) % len(OUTLINE_COLOURS)]
        contours, _ = cv2.findContours(region.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, contours, -1, colour, int(thickness), lineType=cv2.LINE_8)
        if label and instances is not None and region.any():
            vs, us = np.nonzero(region)
            top = int(np.argmin(vs))
            org = (int(max(0, min(us[top] - 6, img.shape[1] - 20))), int(max(14, vs[top] - 4)))
            cv2.putText(img, str(k), org, cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
            cv2.putText(img, str(k), org, cv2.FONT_HERSHEY_SIMPLEX, 0.6, colour, 1, cv2.LINE_AA)
    return img
