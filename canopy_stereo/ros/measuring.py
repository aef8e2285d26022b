"""The graph's outputs measured: ``left/image_rect_color`` + ``disparity`` -> the plant's traits.

The ROS side of the package's one measuring pipeline
(:func:`canopy_stereo.pipeline.plant.measure_plant`): ``demo``, ``view`` and the
measuring nodes hand it the rectified left image and the ``stereo_msgs/DisparityImage``
of one stamp; the numbers are those of ``reconstruct --measure`` and ``batch`` for the
same pair. No rclpy import (messages arrive decoded).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.pipeline.plant import PlantMeasurement, measure_plant


def rectified_disparity(frame) -> np.ndarray:
    """``u_left - u_right`` (float32 pixels, -1 = none) of a
    :class:`~canopy_stereo.ros.convert.DisparityFrame` from the package's graph: its
    rectifications give both rectified cameras one principal point, so the message's
    values need no offset."""
    return np.where(np.isfinite(frame.disparity), frame.disparity, np.float32(-1)).astype(np.float32)


def measure_graph_frame(left_rect_bgr, frame, rig, **options) -> PlantMeasurement:
    """:func:`~canopy_stereo.pipeline.plant.measure_plant` of one graph frame: the rectified
    left image (BGR), its ``DisparityFrame`` and the rig (its rectification, as
    ``rectify_node`` makes it); ``options`` are measure_plant's keyword options."""
    from canopy_stereo.pipeline.reconstruct import rectify_rig

    return measure_plant(left_rect_bgr, rectified_disparity(frame), rig, rectification=rectify_rig(rig),
                         **options)
