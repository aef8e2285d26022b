"""Cleaning binary masks: small regions dropped, small holes filled (image pixels only)."""
from __future__ import annotations

import numpy as np


def clean_mask_regions(mask: np.ndarray, min_pixels: int = 0, *, fill_holes_below: int = 0) -> np.ndarray:
    """Binary mask without 8-connected regions smaller than ``min_pixels`` and with
    holes (4-connected, not touching the border) smaller than ``fill_holes_below``
    filled; returns (H, W) bool."""
    import cv2

    m = np.asarray(mask).astype(bool)
    if min_pixels > 0 and m.any():
        n, lab, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
        small = np.nonzero(stats[:, cv2.CC_STAT_AREA] < min_pixels)[0]
        m &= ~np.isin(lab, small[small != 0])
    if fill_holes_below > 0 and not m.all():
        n, lab, stats, _ = cv2.connectedComponentsWithStats((~m).astype(np.uint8), connectivity=4)
        border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        holes = [i for i in range(1, n) if i not in border and stats[i, cv2.CC_STAT_AREA] < fill_holes_below]
        m |= np.isin(lab, holes)
    return m
