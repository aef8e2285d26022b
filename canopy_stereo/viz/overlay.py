"""The mask overlay picture: a plant mask's outline drawn over the image it was found on.

Every command that masks writes one next to its outputs (``<name>_overlay.png``), so a
user sees at a glance what was measured as plant: the masked area tinted, its outline
in a bright colour, and a one-line caption (what the mask is, how much of the image).
"""
from __future__ import annotations

import cv2
import numpy as np

#: Outline colour (BGR: magenta, visible on green and brown) and its thickness (px).
OUTLINE_BGR = (255, 0, 255)
OUTLINE_PX = 2


def mask_overlay(image_bgr: np.ndarray, mask: np.ndarray, *, caption: str = "") -> np.ndarray:
    """BGR uint8 picture of ``image_bgr`` (H, W[, 3]) with ``mask`` (H, W, non-zero = plant)
    tinted and outlined, and ``caption`` (plus the mask's share of the image) at the top."""
    img = np.asarray(image_bgr)
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    m = np.asarray(mask) > 0
    if m.shape != img.shape[:2]:
        raise ValueError(f"mask is {m.shape[1]}x{m.shape[0]} but the image is {img.shape[1]}x{img.shape[0]}")
    out = img.astype(np.float32)
    out[~m] *= 0.55  # the rest dimmed: the plant stands out
    out = np.clip(out, 0, 255).astype(np.uint8)
    contours, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(out, contours, -1, OUTLINE_BGR, OUTLINE_PX, lineType=cv2.LINE_AA)
    text = (caption + ": " if caption else "") + f"mask {m.mean() * 100:.1f} % of the image"
    scale = max(0.4, img.shape[1] / 1400.0)
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    cv2.rectangle(out, (0, 0), (min(tw + 10, out.shape[1]), th + base + 8), (255, 255, 255), -1)
    cv2.putText(out, text, (5, th + 4), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out
