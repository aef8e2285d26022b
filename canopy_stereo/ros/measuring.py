"""The graph's frames measured: ``left/image_raw`` + ``disparity`` -> the plant's traits.

The ROS side of the package's one measuring pipeline
(:func:`canopy_stereo.measure.plant.measure_plant`): ``demo``, ``view`` and the
measuring nodes hand it the raw left image and the ``stereo_msgs/DisparityImage``
of one stamp; the numbers are those of ``reconstruct --measure`` and ``batch`` for the
same pair. No rclpy import (messages arrive decoded).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.measure.plant import PlantMeasurement, measure_plant


def rectified_disparity(frame, *, doffs: float = 0.0) -> np.ndarray:
    """``u_left - u_right`` (float32 pixels, -1 = none) of a
    :class:`~canopy_stereo.ros.convert.DisparityFrame`: the message's values (``f t / Z``,
    reduced by the rectified cameras' ``doffs = cx_left - cx_right``, as ``disparity_node``
    publishes them) plus ``doffs`` (0 but for a pair that was rectified already, e.g.
    Middlebury's, whose rectification keeps both principal points)."""
    d = frame.disparity + np.float32(doffs)
    return np.where(np.isfinite(d), d, np.float32(-1)).astype(np.float32)


def measure_graph_frame(left_bgr, frame, rig, *, mask_rect=None, **options) -> PlantMeasurement:
    """:func:`~canopy_stereo.measure.plant.measure_plant` of one graph frame: the raw left
    image (BGR, ``left/image_raw`` of the frame's stamp), its ``DisparityFrame`` and the rig
    (its rectification as ``rectify_node`` makes it,
    :func:`~canopy_stereo.geometry.rig_rectification.rectification_for_rig`).

    Without the raw image (a bag of recorded outputs), ``mask_rect`` (the recorded
    ``left/mask``, rectified grid) is carried to the original grid and given as the mask.
    ``options`` are measure_plant's keyword options."""
    from canopy_stereo.geometry.rig_rectification import rectification_for_rig
    from canopy_stereo.measure.plant import mask_on_original

    rect = rectification_for_rig(rig)
    disparity = rectified_disparity(frame, doffs=rect.doffs)
    if left_bgr is None and mask_rect is not None and "mask" not in options:
        options["mask"] = mask_on_original(mask_rect, disparity, rig, rect)
    return measure_plant(left_bgr, disparity, rig, rectification=rect, **options)
