"""Kalibr ``camchain.yaml``: two pinhole cameras (``radtan`` or ``equidistant``) and ``T_cn_cnm1``.

Each camera ``camN`` has ``camera_model`` (``pinhole``), ``intrinsics`` ``[fu, fv, pu, pv]``,
``distortion_model`` (``radtan``: OpenCV's ``[k1, k2, p1, p2]``; ``equidistant``: OpenCV
fisheye ``[k1, k2, k3, k4]``; ``none``), ``distortion_coeffs``, ``resolution`` ``[w, h]``;
``cam1`` has ``T_cn_cnm1``, the 4x4 transform from cam0's frame to cam1's
(``X_cam1 = T X_cam0``), in metres. ``cam0`` is the left camera unless another pair is named.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

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

CAMERA_FIELDS = ("camera_model", "intrinsics", "distortion_model", "distortion_coeffs", "resolution",
                 "T_cn_cnm1", "T_cam_imu", "cam_overlaps", "rostopic", "timeshift_cam_imu",
                 "line_delay")
#: Kalibr distortion model -> REP 104 model.
DISTORTION_MODELS = {"radtan": "plumb_bob", "equidistant": "equidistant", "none": "plumb_bob"}
#: Unit of Kalibr's translations.
KALIBR_UNIT = "m"


def _camera(doc: dict, name: str, source: str) -> CameraIntrinsics:
    where = f"{source} {name}"
    cam = doc[name]
    if not isinstance(cam, dict):
        raise CalibrationError(f"{where} must be a mapping")
    for key in cam:
        if key not in CAMERA_FIELDS:
            raise unknown_field(where, key, CAMERA_FIELDS)
    missing = [k for k in ("camera_model", "intrinsics", "distortion_model", "resolution") if k not in cam]
    if missing:
        raise CalibrationError(f"{where}: missing {', '.join(missing)}")
    if cam["camera_model"] != "pinhole":
        raise CalibrationError(f"{where}: camera_model {cam['camera_model']!r} is not supported (pinhole only)")
    kmodel = cam["distortion_model"]
    if kmodel not in DISTORTION_MODELS:
        raise CalibrationError(f"{where}: distortion_model {kmodel!r} is not supported "
                               f"(expected {', '.join(DISTORTION_MODELS)})")
    fu, fv, pu, pv = matrix(cam["intrinsics"], (4,), where, "intrinsics")
    K = intrinsics([[fu, 0, pu], [0, fv, pv], [0, 0, 1]], where, "intrinsics")
    model = DISTORTION_MODELS[kmodel]
    coeffs = cam.get("distortion_coeffs") or ([] if kmodel == "none" else None)
    if coeffs is None:
        raise CalibrationError(f"{where}: missing distortion_coeffs")
    D = distortion(coeffs, model, where, "distortion_coeffs")
    if kmodel == "none" and np.any(D):
        raise CalibrationError(f"{where}: distortion_model none with non-zero distortion_coeffs")
    res = cam["resolution"]
    if not isinstance(res, list) or len(res) != 2:
        raise CalibrationError(f"{where}: resolution must be [width, height]")
    return CameraIntrinsics(K=K, D=D if D.size else np.zeros(5), model=model,
                            size=image_size(res[0], res[1], where))


def import_kalibr(paths, *, unit: str | None = None):
    """``camchain.yaml`` -> rig (cam0 left, cam1 right; unit metres unless ``unit``)."""
    if len(paths) != 1:
        raise CalibrationError(f"--from kalibr takes one camchain.yaml; got {len(paths)} files")
    path = Path(paths[0])
    source = str(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CalibrationError(f"cannot read {path}: {exc.strerror or exc}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{source} is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source} is not a Kalibr camchain (expected cam0, cam1)")
    for key in doc:
        if not (isinstance(key, str) and key.startswith("cam") and key[3:].isdigit()):
            raise unknown_field(source, key, ("cam0", "cam1"))
    if "cam0" not in doc or "cam1" not in doc:
        raise CalibrationError(f"{source}: needs cam0 and cam1")
    left, right = _camera(doc, "cam0", source), _camera(doc, "cam1", source)
    if "T_cn_cnm1" not in doc["cam1"]:
        raise CalibrationError(f"{source} cam1: missing T_cn_cnm1 (the cam0 -> cam1 transform)")
    T = matrix(doc["cam1"]["T_cn_cnm1"], (4, 4), f"{source} cam1", "T_cn_cnm1")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise CalibrationError(f"{source} cam1: T_cn_cnm1's last row must be [0, 0, 0, 1]")
    R = rotation(T[:3, :3], f"{source} cam1", "the rotation of T_cn_cnm1")
    return rig_from_cameras(left, right, R, T[:3, 3], unit=unit or KALIBR_UNIT, source=source)
