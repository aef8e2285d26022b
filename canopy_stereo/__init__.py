"""canopy_stereo: metric stereo reconstruction and measurement of plant canopies.

The package is a pure numpy/OpenCV core grouped by what it does
(:mod:`canopy_stereo.geometry`, :mod:`canopy_stereo.disparity`,
:mod:`canopy_stereo.io`, ...), thin ROS 2 node shells under
:mod:`canopy_stereo.ros` and one command line, ``canopy-stereo``
(:mod:`canopy_stereo.cli`).

Conventions used everywhere:

* Pixel coordinates ``(u, v)``: ``u`` to the right (column), ``v`` down (row),
  the centre of the top-left pixel at ``(0, 0)``.
* World points are in the unit of the rig file (``world_unit``, millimetres
  for the paper's rig); ROS messages carry metres.
* A camera is a 3x4 projection matrix ``P`` mapping homogeneous world points to
  homogeneous pixels: ``x ~ P @ [X, Y, Z, 1]``.
* Invalid disparities are negative (-1).
"""
from canopy_stereo.errors import CanopyStereoError


def _version() -> str:
    """package.xml's version (the one place it is written) beside a source tree, else the
    installed distribution's (which setup.py took from package.xml)."""
    import re
    from importlib.metadata import version
    from pathlib import Path

    xml = Path(__file__).resolve().parent.parent / "package.xml"
    if xml.is_file():
        found = re.search(r"<version>\s*([^<\s]+)\s*</version>", xml.read_text(encoding="utf-8"))
        if found:
            return found.group(1)
    return version("canopy_stereo")


__version__ = _version()
__all__ = ["CanopyStereoError", "__version__"]
