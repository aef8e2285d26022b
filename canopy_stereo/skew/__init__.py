"""Capture-skew compensation for free-running stereo webcams (pure core, no ROS).

:class:`SkewCompensator` brings the right image of each raw pair to the left
image's instant along the right camera's own image motion between consecutive
frames (:func:`image_motion`, :func:`move_in_time`); ``rectify_node``,
``canopy-stereo run`` (through the node) and ``canopy-stereo batch`` call it on
every pair, before rectification. See :mod:`canopy_stereo.skew.compensator`.
"""
from canopy_stereo.skew.compensator import SkewCompensator, SkewReport
from canopy_stereo.skew.motion import ImageMotion, image_motion, move_in_time

__all__ = ["ImageMotion", "SkewCompensator", "SkewReport", "image_motion", "move_in_time"]
