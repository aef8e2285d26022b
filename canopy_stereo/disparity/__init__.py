"""Dense disparity matchers behind one interface.

A matcher takes two *rectified* images of equal size (uint8 grey or BGR) and
returns the left disparity map as float32 (H, W) in pixels, with
``u_right = u_left - d`` and invalid pixels negative (-1). Matchers are looked
up by name (``sgbm``, ``elas``) so the CLI, the pipeline and the ROS nodes can
switch between them with one string; the registry (:mod:`.registry`) also holds each
matcher's parameter schema, presets and disparity resolution, from which the CLI options,
``disparity_node``'s parameters and the validation are derived.
"""
from canopy_stereo.disparity.registry import (
    DEFAULT_MATCHER,
    INVALID_DISPARITY,
    MatcherParameter,
    MatcherSpec,
    available_matchers,
    compute_disparity,
    declare,
    default_matcher,
    get_matcher,
    matcher_names,
    matcher_spec,
    preset_names,
    register_matcher,
)

__all__ = ["DEFAULT_MATCHER", "INVALID_DISPARITY", "MatcherParameter", "MatcherSpec", "available_matchers",
           "compute_disparity", "declare", "default_matcher", "get_matcher", "matcher_names", "matcher_spec",
           "preset_names", "register_matcher"]
