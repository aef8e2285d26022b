"""Dense disparity matchers behind one interface.

A matcher takes two *rectified* images of equal size (uint8 grey or BGR) and
returns the left disparity map as float32 (H, W) in pixels, with
``u_right = u_left - d`` and invalid pixels negative (-1). Matchers are looked
up by name (``sgbm``, ``elas``) so the CLI, the pipeline and the ROS nodes can
switch between them with one string.
"""
from canopy_stereo.disparity.registry import (
    INVALID_DISPARITY,
    available_matchers,
    compute_disparity,
    get_matcher,
    matcher_names,
    register_matcher,
)

__all__ = ["INVALID_DISPARITY", "available_matchers", "compute_disparity", "get_matcher",
           "matcher_names", "register_matcher"]
