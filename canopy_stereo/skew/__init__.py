"""Capture-skew compensation for free-running stereo webcams (pure core, no ROS).

:class:`SkewCompensator` brings the right image of each raw pair to the left
image's instant along the right camera's own image motion between consecutive
frames (:func:`image_motion`, :func:`move_in_time`); ``rectify_node``,
``canopy-stereo run`` (through the node) and ``canopy-stereo batch`` call it on
every pair (the node composes the shift into its rectification map,
:meth:`SkewShift.apply`; batch moves the raw image). See :mod:`canopy_stereo.skew.compensator`.
"""
from canopy_stereo.skew.compensator import SkewCompensator, SkewReport, SkewShift
from canopy_stereo.skew.motion import ImageMotion, image_motion, move_in_time, sample_moved

__all__ = ["ImageMotion", "SkewCompensator", "SkewReport", "SkewShift", "image_motion", "move_in_time",
           "sample_moved"]
