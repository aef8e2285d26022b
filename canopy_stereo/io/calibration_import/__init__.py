"""Import the stereo calibrations other tools write, as a rig (``canopy-stereo calibrate --from``).

Formats (:data:`FORMATS`; one module each):

* ``ros-yaml``: ROS ``camera_calibration`` camera_info YAML, ``left.yaml right.yaml``
  (:mod:`.ros`);
* ``ros-ini``: its INI output, a stereo ``ost.txt`` or ``left.ini right.ini`` (:mod:`.ros`);
* ``kalibr``: Kalibr ``camchain.yaml``, pinhole with ``radtan`` or ``equidistant`` (:mod:`.kalibr`);
* ``opencv``: OpenCV ``stereoCalibrate`` results in FileStorage YAML or XML (:mod:`.opencv`);
* ``middlebury``: Middlebury 2014 ``calib.txt`` (:mod:`.middlebury`).

The rig's world frame is the left camera's optical frame (``P_left = K_left [I | 0]``), its
unit the file's (ROS, Kalibr: metres; Middlebury: millimetres; OpenCV: ``unit``, default
millimetres), the lens distortion is kept (``plumb_bob``, ``rational_polynomial`` or
``equidistant``). Every problem (unknown or misspelt field, image sizes that differ, a ``R``
that is not a rotation, fields that contradict each other) is one
:class:`~canopy_stereo.errors.CalibrationError` line naming the file and the field.
"""
from __future__ import annotations

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.rig import Rig
from canopy_stereo.io.calibration_import.kalibr import import_kalibr
from canopy_stereo.io.calibration_import.middlebury import import_middlebury
from canopy_stereo.io.calibration_import.opencv import import_opencv
from canopy_stereo.io.calibration_import.ros import import_ros_ini, import_ros_yaml

#: format name -> importer(paths, *, unit)
FORMATS = {"ros-yaml": import_ros_yaml, "ros-ini": import_ros_ini, "kalibr": import_kalibr,
           "opencv": import_opencv, "middlebury": import_middlebury}

__all__ = ["FORMATS", "import_calibration"]


def import_calibration(fmt: str, paths, *, unit: str | None = None, image_size=None) -> Rig:
    """The rig of calibration file(s) ``paths`` written in format ``fmt`` (a key of
    :data:`FORMATS`). ``unit``: the unit of the file's translations when the format has
    none of its own (OpenCV; default mm) or to override it; ``image_size``: ``(w, h)`` for
    an OpenCV file without one. Raises :class:`CalibrationError` (one line)."""
    if fmt not in FORMATS:
        raise CalibrationError(f"unknown calibration format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if fmt == "opencv":
        return import_opencv(list(paths), unit=unit, image_size_wh=image_size)
    if image_size is not None:
        raise CalibrationError(f"--image-size applies to --from opencv only ({fmt} files hold the size)")
    return FORMATS[fmt](list(paths), unit=unit)
