"""OpenCV ``stereoCalibrate`` results as a ``cv::FileStorage`` file (YAML or XML).

The names of OpenCV's ``stereo_calib`` sample: ``M1``, ``D1``, ``M2``, ``D2`` (camera
matrices and distortion, OpenCV's model with 4, 5, 8, 12 or 14 coefficients) and ``R``,
``T`` (``X_2 = R X_1 + T``, ``T`` in the unit of the board's square size); optionally the
``stereoRectify`` outputs ``R1``, ``R2``, ``P1``, ``P2``, ``Q`` (checked against ``R``,
``T``), ``E``, ``F``. The sample writes ``intrinsics.yml`` and ``extrinsics.yml``: pass
both (their fields are merged). FileStorage keeps no image size unless the writer added
``image_width``/``image_height`` (or ``imageSize``/``image_size`` ``[w, h]``); else give
``--image-size``. Camera 1 is the left camera.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.io.calibration_import.stereo import (
    CameraIntrinsics,
    distortion,
    image_size,
    intrinsics,
    matrix,
    rig_from_cameras,
    rotation,
    unknown_field,
)

REQUIRED = ("M1", "D1", "M2", "D2", "R", "T")
OPTIONAL = ("R1", "R2", "P1", "P2", "Q", "E", "F", "image_width", "image_height", "imageSize", "image_size",
            "rms", "calibration_time", "nframes", "validRoi1", "validRoi2")


def read_filestorage(path) -> dict:
    """The top-level fields of a FileStorage file: name -> float64 array (or str)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"cannot read {path}: no such file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:  # SystemError: a parse error inside the constructor
        cause = exc.__cause__ or exc
        raise CalibrationError(f"{path} is not a valid OpenCV FileStorage file: "
                               f"{str(cause).strip().splitlines()[-1]}") from None
    try:
        if not fs.isOpened():
            raise CalibrationError(f"{path} is not an OpenCV FileStorage file (YAML or XML)")
        root = fs.root()
        out: dict[str, Any] = {}
        for name in root.keys():
            node = fs.getNode(name)
            if node.isString():
                out[name] = node.string()
            elif node.isInt() or node.isReal():
                out[name] = np.array([node.real()])
            elif node.isSeq():
                out[name] = np.array([node.at(i).real() for i in range(node.size())])
            else:
                m = node.mat()
                if m is None:
                    raise CalibrationError(f"{path}: field {name!r} is neither a matrix nor numbers")
                out[name] = np.asarray(m, np.float64)
        return out
    finally:
        fs.release()


def _size(fields: dict, source: str, given) -> tuple[int, int]:
    if "image_width" in fields or "image_height" in fields:
        try:
            return image_size(fields["image_width"].ravel()[0], fields["image_height"].ravel()[0], source)
        except KeyError:
            raise CalibrationError(f"{source}: image_width and image_height go together") from None
    for key in ("imageSize", "image_size"):
        if key in fields:
            wh = matrix(fields[key], (2,), source, key)
            return image_size(wh[0], wh[1], source)
    if given is None:
        raise CalibrationError(f"{source}: no image size in the file; give --image-size WxH")
    return image_size(given[0], given[1], "--image-size")


def import_opencv(paths, *, unit: str | None = None, image_size_wh=None):
    """FileStorage file(s) -> rig (world unit ``unit``, default ``mm``: the unit of ``T``)."""
    if not 1 <= len(paths) <= 2:
        raise CalibrationError(f"--from opencv takes one or two FileStorage files; got {len(paths)}")
    fields: dict = {}
    for p in paths:
        for name, value in read_filestorage(p).items():
            if name in fields:
                raise CalibrationError(f"{p}: field {name!r} is also in {paths[0]}")
            if name not in REQUIRED + OPTIONAL:
                raise unknown_field(str(p), name, REQUIRED + OPTIONAL)
            fields[name] = value
    source = " + ".join(str(p) for p in paths)
    missing = [k for k in REQUIRED if k not in fields]
    if missing:
        raise CalibrationError(f"{source}: missing {', '.join(missing)}")
    size = _size(fields, source, image_size_wh)
    cams = []
    for i in (1, 2):
        D = distortion(np.asarray(fields[f"D{i}"]).ravel(), None, source, f"D{i}")
        cams.append(CameraIntrinsics(K=intrinsics(fields[f"M{i}"], source, f"M{i}"), D=D,
                                     model="plumb_bob" if D.size <= 5 else "rational_polynomial", size=size))
    R = rotation(fields["R"], source, "R")
    T = matrix(fields["T"], (3,), source, "T")
    _check_rectification(fields, R, T, source)
    return rig_from_cameras(cams[0], cams[1], R, T, unit=unit or "mm", source=source)


def _check_rectification(fields: dict, R, T, source: str) -> None:
    """``R1``, ``R2``, ``P1``, ``P2`` when present must be a rectification of ``R``, ``T``."""
    present = [k for k in ("R1", "R2", "P1", "P2") if k in fields]
    if not present:
        return
    if len(present) != 4:
        raise CalibrationError(f"{source}: R1, R2, P1, P2 go together (found only {', '.join(present)})")
    R1, R2 = rotation(fields["R1"], source, "R1"), rotation(fields["R2"], source, "R2")
    P1, P2 = matrix(fields["P1"], (3, 4), source, "P1"), matrix(fields["P2"], (3, 4), source, "P2")
    if not (P2[0, 0] > 0 and P2[1, 1] > 0):
        raise CalibrationError(f"{source}: P2 has no focal length")
    if not np.allclose(P1[:, :3], P2[:, :3], rtol=1e-6, atol=1e-6) or np.any(P1[:, 3]):
        raise CalibrationError(f"{source}: P1 and P2 are not one rectified pair (different intrinsics, "
                               "or P1 has a baseline)")
    # the rectified right camera sits at R1 C_right in the rectified frame: P2's (Tx, Ty) / f
    t_rect = np.array([P2[0, 3] / P2[0, 0], P2[1, 3] / P2[1, 1], P2[2, 3]])
    want = R2 @ T
    rel = np.linalg.norm(t_rect - want) / np.linalg.norm(T)
    rot = np.abs(R2.T @ R1 - R).max()
    if rel > 1e-3 or rot > 1e-4:
        raise CalibrationError(f"{source}: R1, R2, P1, P2 are not a rectification of R, T "
                               f"(translation off by {100 * rel:.2g} %, rotation by {rot:.2g})")
