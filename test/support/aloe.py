"""The held-out real plant scene with large disparities for the graph benchmarks: Middlebury
2006 Aloe at full size (``../shared/data/opencv_aloe_fullsize``, 1282x1110, ground-truth
disparities to 211 px), resized by :data:`ALOE_SCALE` so that its 640x480 window holds
disparities to about 130 px (issue 28's second 640x480 scene; ``bags/plants.mcap`` holds 0-81).

Middlebury's pair is rectified already: the rig below has one principal point for both
cameras, the focal length (3740 px at full size) and baseline (160 mm) of the 2006 dataset's
description, and no disparity offset (the 2006 images are cropped by an offset the data here
does not carry), so its depths are not the scene's: the benchmark measures rate, not accuracy.
Not bundled with the package: it needs the shared data beside the checkout.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

#: Scale of the full-size pair for the benchmarks (1282x1110 -> 795x688).
ALOE_SCALE = 0.62
#: Focal length (pixels, full size) and baseline (mm) of Middlebury 2006.
ALOE_FOCAL_PX, ALOE_BASELINE_MM = 3740.0, 160.0
#: Largest ground-truth disparity at full size (pixels; aloeGT.png's maximum).
ALOE_MAX_DISPARITY = 211
#: Crop of the scaled pair to 640x480 (x0, y0), centred.
ALOE_CROP = (77, 104)


def aloe_dir(data: Path | None = None) -> Path:
    """``opencv_aloe_fullsize`` under ``data`` (default: ``../shared/data`` beside the checkout);
    FileNotFoundError naming it when absent."""
    data = Path(data) if data is not None else Path(__file__).resolve().parents[2].parent / "shared" / "data"
    folder = data / "opencv_aloe_fullsize"
    if not (folder / "aloeL.jpg").is_file():
        raise FileNotFoundError(f"the aloe scene needs {folder}/aloeL.jpg and aloeR.jpg (the shared data "
                                "beside the checkout)")
    return folder


def aloe_source(data: Path | None = None):
    """``(rig, left, right)``: the scaled Aloe pair (uint8 BGR (688, 795, 3) each) and its rig
    (:class:`~canopy_stereo.io.rig.Rig` in millimetres, world = left camera, with the search
    range 0 .. the scaled largest disparity + 4 px)."""
    import cv2

    from canopy_stereo.io.rig import Rig

    folder = aloe_dir(data)
    images = []
    for name in ("aloeL.jpg", "aloeR.jpg"):
        img = cv2.imread(str(folder / name), cv2.IMREAD_COLOR)
        if img is None:
            raise FileNotFoundError(f"cannot read {folder / name}")
        h, w = img.shape[:2]
        images.append(cv2.resize(img, (round(w * ALOE_SCALE), round(h * ALOE_SCALE)), interpolation=cv2.INTER_AREA))
    h, w = images[0].shape[:2]
    s = ALOE_SCALE
    f = ALOE_FOCAL_PX * s
    K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
    P_left = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = K @ np.hstack([np.eye(3), np.array([[-ALOE_BASELINE_MM], [0.0], [0.0]])])
    extra = {"disp_min": 0, "disp_max": int(np.ceil(ALOE_MAX_DISPARITY * s)) + 4}
    return Rig(P_left=P_left, P_right=P_right, image_size=(w, h), world_unit="mm", extra=extra), images[0], images[1]
