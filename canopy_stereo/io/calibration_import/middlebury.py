"""Middlebury 2014 ``calib.txt``: two rectified cameras ``cam0``/``cam1``, ``baseline`` (mm).

The pair is already rectified and undistorted: ``cam1 = cam0`` but for ``cx`` (``doffs =
cx1 - cx0``), the right camera ``baseline`` millimetres along x. The reader is
:func:`canopy_stereo.io.middlebury.read_middlebury_calib`; here the fields are checked.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.io.calibration_import.stereo import CameraIntrinsics, image_size, intrinsics, rig_from_cameras

FIELDS = ("cam0", "cam1", "doffs", "baseline", "width", "height", "ndisp", "isint", "vmin", "vmax",
          "dyavg", "dymax")


def import_middlebury(paths, *, unit: str | None = None):
    """``calib.txt`` -> rig in millimetres (the file's unit; ``unit`` must be ``mm`` if given)."""
    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.io.middlebury import middlebury_disparity_range, read_middlebury_calib

    if len(paths) != 1:
        raise CalibrationError(f"--from middlebury takes one calib.txt; got {len(paths)} files")
    source = str(paths[0])
    if unit not in (None, "mm"):
        raise CalibrationError(f"{source}: a Middlebury baseline is in mm (--unit {unit} does not apply)")
    try:
        calib = read_middlebury_calib(paths[0], fields=FIELDS)
    except CalibrationError:
        raise
    except CanopyStereoError as exc:
        raise CalibrationError(str(exc)) from None
    for key, value in calib.items():
        if isinstance(value, str):
            raise CalibrationError(f"{source}: {key} must be a number, got {value!r}")
    K0, K1 = intrinsics(calib["cam0"], source, "cam0"), intrinsics(calib["cam1"], source, "cam1")
    if not (np.isclose(K0[0, 0], K1[0, 0]) and np.isclose(K0[1, 1], K1[1, 1]) and np.isclose(K0[1, 2], K1[1, 2])):
        raise CalibrationError(f"{source}: cam0 and cam1 differ in more than cx (not a rectified pair)")
    if abs((K1[0, 2] - K0[0, 2]) - calib["doffs"]) > 1e-3:
        raise CalibrationError(f"{source}: doffs {calib['doffs']:g} is not cx1 - cx0 = {K1[0, 2] - K0[0, 2]:g}")
    B = float(calib["baseline"])
    if not B > 0:
        raise CalibrationError(f"{source}: baseline must be positive (mm), got {B:g}")
    size = image_size(calib["width"], calib["height"], source)
    extra = middlebury_disparity_range(calib)
    cams = [CameraIntrinsics(K=K, D=np.zeros(5), model="plumb_bob", size=size) for K in (K0, K1)]
    return rig_from_cameras(cams[0], cams[1], np.eye(3), [-B, 0.0, 0.0], unit="mm", source=source, extra=extra)
