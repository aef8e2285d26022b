"""OpenCV semi-global block matching (Hirschmueller 2008) as a registered matcher."""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.io.images import to_gray

#: ``mode`` -> OpenCV StereoSGBM mode: ``sgbm`` (5 paths), ``hh`` (full 8 paths), ``3way``.
SGBM_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
              "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY}


def sgbm_disparity(left: np.ndarray, right: np.ndarray, *, disp_min: int = 0,
                   disp_max: int = 128, block_size: int = 5, p1: int | None = None,
                   p2: int | None = None, uniqueness: int = 10, speckle_window: int = 100,
                   speckle_range: int = 2, disp12_max_diff: int = 1,
                   mode: str = "sgbm") -> np.ndarray:
    """Left disparity (float32 (H, W), pixels, invalid = -1) by OpenCV StereoSGBM.

    The search range ``[disp_min, disp_max]`` is widened to a multiple of 16 as
    OpenCV requires. ``p1``/``p2`` default to 8 and 32 times ``block_size**2``
    (grey input). ``mode`` is ``sgbm``, ``hh`` (full 8-path) or ``3way``.
    """
    gl, gr = to_gray(left, "left"), to_gray(right, "right")
    num = int(np.ceil((disp_max - disp_min + 1) / 16.0)) * 16
    matcher = cv2.StereoSGBM_create(  # type: ignore[attr-defined]  # (absent from OpenCV 5.0's stubs)
        minDisparity=int(disp_min), numDisparities=num, blockSize=int(block_size),
        P1=int(p1 if p1 is not None else 8 * block_size ** 2),
        P2=int(p2 if p2 is not None else 32 * block_size ** 2),
        disp12MaxDiff=int(disp12_max_diff), uniquenessRatio=int(uniqueness),
        speckleWindowSize=int(speckle_window), speckleRange=int(speckle_range),
        mode=SGBM_MODES[mode])
    raw = matcher.compute(gl, gr)
    disp = raw.astype(np.float32) / 16.0
    disp[raw < (disp_min * 16)] = -1.0
    disp[disp > disp_max] = -1.0
    return disp
