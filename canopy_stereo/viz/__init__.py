"""Looking at what canopy_stereo produces: a Rerun viewer and self-explaining pictures.

* :mod:`canopy_stereo.viz.colour`: the package's one disparity/depth colour map and
  PNGs with a colour bar and units (numpy + OpenCV only).
* :mod:`canopy_stereo.viz.rerun_log`: logging frames (cloud, rectified image,
  depth with the camera's pinhole and pose, plant mask, leaves, canopy box) to
  Rerun, the saved blueprint, and the sinks (``.rrd`` file, native viewer, the
  web viewer served on localhost). Needs the optional extra ``viz``
  (``pip install 'canopy_stereo[viz]'``, rerun-sdk); no ROS import.
* :mod:`canopy_stereo.ros.viewer` (the ROS side): what to show from a bag (run its
  raw frames through the graph, or show its recorded outputs) or a live graph.
"""
from __future__ import annotations

#: pip requirement of the viewer (kept in step with setup.py's ``viz`` extra).
RERUN_REQUIREMENT = "rerun-sdk==0.41.0"

#: One line telling what to install when rerun-sdk is missing.
INSTALL_HINT = (f"the viewer needs the optional extra 'viz': pip install 'canopy_stereo[viz]' "
                f"(or pip install '{RERUN_REQUIREMENT}')")


def rerun_available() -> bool:
    """True when rerun-sdk can be imported."""
    try:
        import rerun  # noqa: F401
    except ImportError:
        return False
    return True
