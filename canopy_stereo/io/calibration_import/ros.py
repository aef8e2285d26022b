"""ROS ``camera_calibration`` output: camera_info YAML (``left.yaml``/``right.yaml``) and INI (``ost.txt``).

``cameracalibrator`` (image_pipeline) writes each camera's ``K``, ``D`` (+ model), the
rectifying rotation ``R`` (raw -> rectified camera) and the rectified projection
``P = [K' | (Tx, Ty, 0)]`` with ``Tx = -fx' B`` (REP 104; ``B`` in metres, the unit of its
``--square``). The extrinsics follow: ``X_rect = R_left X_left`` and
``X_right = R_right^T (X_rect + (Tx / fx', Ty / fy', 0))``.

YAML keys (camera_calibration_parsers): ``image_width``, ``image_height``, ``camera_name``,
``camera_matrix``, ``distortion_model``, ``distortion_coefficients``,
``rectification_matrix``, ``projection_matrix`` (matrices as ``{rows, cols, data}``).
INI (``ost.txt``): ``[image]`` with ``width``/``height``, then ``[<name>]`` with ``camera
matrix``, ``distortion``, ``rectification``, ``projection``; a stereo ``ost.txt`` holds both
cameras (sections ending ``/left`` and ``/right``). The INI names no distortion model:
5 coefficients are ``plumb_bob``, 8 ``rational_polynomial``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.frames import CameraCalibration
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

YAML_FIELDS = ("image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
               "distortion_coefficients", "rectification_matrix", "projection_matrix")
_INI_FIELDS = {"camera matrix": (3, 3), "distortion": None, "rectification": (3, 3), "projection": (3, 4)}
#: Unit of ROS camera_info translations (REP 103; cameracalibrator's --square is in metres).
ROS_UNIT = "m"


class _RosCamera:
    """One camera_info: intrinsics + the rectification (``R``, ``P``)."""

    def __init__(self, cam: CameraIntrinsics, R, P, name: str, source: str):
        self.cam, self.R, self.P, self.name, self.source = cam, R, P, name, source


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise CalibrationError(f"{path} is not a text file") from None


def _yaml_matrix(doc, key, shape, source):
    value = doc.get(key)
    if not isinstance(value, dict) or "data" not in value:
        raise CalibrationError(f"{source}: {key} must be a mapping with rows, cols and data")
    for k in value:
        if k not in ("rows", "cols", "data"):
            raise unknown_field(f"{source}: {key}", k, ("rows", "cols", "data"))
    data = value["data"]
    n = len(data) if isinstance(data, list) else -1
    rows, cols = value.get("rows"), value.get("cols")
    if rows is not None and cols is not None and rows * cols != n:
        raise CalibrationError(f"{source}: {key} says {rows}x{cols} but holds {n} numbers")
    if shape is None:
        return matrix(data, (max(n, 0),), source, key)
    return matrix(data, shape, source, key)


def read_camera_info_yaml(path) -> _RosCamera:
    """One camera_info YAML file (camera_calibration_parsers' format)."""
    path = Path(path)
    source = str(path)
    try:
        doc = yaml.safe_load(_read_text(path))
    except yaml.YAMLError as exc:
        raise CalibrationError(f"{source} is not valid YAML: {str(exc).splitlines()[0]}") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source} is not a camera_info YAML file (expected a mapping)")
    for key in doc:
        if key not in YAML_FIELDS:
            raise unknown_field(source, key, YAML_FIELDS)
    missing = [k for k in ("image_width", "image_height", "camera_matrix", "distortion_coefficients",
                           "rectification_matrix", "projection_matrix") if k not in doc]
    if missing:
        raise CalibrationError(f"{source}: missing {', '.join(missing)}")
    model = doc.get("distortion_model") or None
    cam = CameraIntrinsics(K=intrinsics(_yaml_matrix(doc, "camera_matrix", (3, 3), source), source, "camera_matrix"),
                           D=distortion(_yaml_matrix(doc, "distortion_coefficients", None, source), model,
                                        source, "distortion_coefficients"),
                           model=model or "plumb_bob",
                           size=image_size(doc["image_width"], doc["image_height"], source))
    if model is None:
        cam = CameraIntrinsics(cam.K, cam.D, "plumb_bob" if cam.D.size <= 5 else "rational_polynomial", cam.size)
    return _RosCamera(cam, rotation(_yaml_matrix(doc, "rectification_matrix", (3, 3), source), source,
                                    "rectification_matrix"),
                      _yaml_matrix(doc, "projection_matrix", (3, 4), source), str(doc.get("camera_name", "")),
                      source)


def read_ost_ini(path) -> list[_RosCamera]:
    """The cameras of an INI calibration file (one, or both of a stereo ``ost.txt``)."""
    path = Path(path)
    source = str(path)
    cams: list[_RosCamera] = []
    size = None
    section: str | None = None
    key: str | None = None
    fields: dict[str, list[list[float]]] = {}
    rows: list[list[float]] = []

    def close_key():
        nonlocal key, rows
        if key is not None:
            fields[key] = rows
        key, rows = None, []

    def close_section():
        nonlocal fields
        close_key()
        if section is None:
            return
        if section == "image":
            if set(fields) - {"width", "height"}:
                raise unknown_field(f"{source} [image]", sorted(set(fields) - {"width", "height"})[0],
                                    ("width", "height"))
            try:
                nonlocal size
                size = image_size(fields["width"][0][0], fields["height"][0][0], f"{source} [image]")
            except (KeyError, IndexError):
                raise CalibrationError(f"{source} [image]: needs width and height") from None
        else:
            cams.append(_ini_camera(section, fields, size, source))
        fields = {}

    for raw in _read_text(path).splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("[") and line.endswith("]"):
            close_section()
            section = line[1:-1].strip()
            continue
        try:
            numbers = [float(v) for v in line.split()]
        except ValueError:
            numbers = None
        if numbers is not None:
            if key is None:
                raise CalibrationError(f"{source}: numbers {line!r} before any field name")
            rows.append(numbers)
            continue
        close_key()
        if section is None:
            raise CalibrationError(f"{source}: field {line!r} outside a [section]")
        if section != "image" and line not in _INI_FIELDS:
            raise unknown_field(f"{source} [{section}]", line, _INI_FIELDS)
        key = line
    close_section()
    if not cams:
        raise CalibrationError(f"{source}: no camera section (expected [image] then [<camera name>])")
    return cams


def _ini_camera(section, fields, size, source) -> _RosCamera:
    where = f"{source} [{section}]"
    if size is None:
        raise CalibrationError(f"{where}: no [image] section with width and height before it")
    missing = [k for k in _INI_FIELDS if k not in fields]
    if missing:
        raise CalibrationError(f"{where}: missing {', '.join(missing)}")

    def flat(k):
        return [v for row in fields[k] for v in row]

    D = np.asarray(flat("distortion"), np.float64)
    if D.size == 4:
        raise CalibrationError(f"{where}: 4 distortion coefficients but the INI format names no model "
                               "(plumb_bob or fisheye?): import the camera_info YAML files instead")
    model = "plumb_bob" if D.size <= 5 else "rational_polynomial"
    cam = CameraIntrinsics(K=intrinsics(matrix(flat("camera matrix"), (3, 3), where, "camera matrix"), where,
                                        "camera matrix"),
                           D=distortion(D, model, where, "distortion"), model=model, size=size)
    return _RosCamera(cam, rotation(matrix(flat("rectification"), (3, 3), where, "rectification"), where,
                                    "rectification"),
                      matrix(flat("projection"), (3, 4), where, "projection"), section, where)


def _left_right(cams: list[_RosCamera], source: str) -> tuple[_RosCamera, _RosCamera]:
    if len(cams) != 2:
        raise CalibrationError(f"{source}: a stereo calibration needs two cameras, found {len(cams)}")
    by_side = {side: [c for c in cams if c.name.rstrip("/").endswith(side)] for side in ("left", "right")}
    if len(by_side["left"]) == 1 and len(by_side["right"]) == 1:
        return by_side["left"][0], by_side["right"][0]
    return cams[0], cams[1]  # the order given: left first


def rig_from_ros(cams: list[_RosCamera], *, unit: str = ROS_UNIT):
    """The rig of a left and a right camera_info (see the module docstring)."""
    source = " + ".join(dict.fromkeys(c.source for c in cams))
    left, right = _left_right(cams, source)
    Pl, Pr = left.P, right.P
    if not (Pl[0, 0] > 0 and Pr[0, 0] > 0 and Pl[1, 1] > 0 and Pr[1, 1] > 0):
        raise CalibrationError(f"{source}: the projection matrices have no focal length (not a stereo calibration)")
    if not np.allclose(Pl[:, :3], Pr[:, :3], rtol=1e-5, atol=1e-3):
        raise CalibrationError(f"{source}: the two projection matrices have different rectified intrinsics "
                               "(not one stereo calibration)")
    if abs(Pl[0, 3]) > 1e-9 or abs(Pl[1, 3]) > 1e-9:
        raise CalibrationError(f"{right.source}: the left camera's projection has a baseline (Tx/Ty); "
                               "are left and right swapped?")
    t = np.array([Pr[0, 3] / Pr[0, 0], Pr[1, 3] / Pr[1, 1], Pr[2, 3]])
    if not np.linalg.norm(t) > 0:
        raise CalibrationError(f"{right.source}: the right projection has no baseline (Tx = Ty = 0): "
                               "a monocular calibration, or left and right are the same file")
    R = right.R.T @ left.R
    T = right.R.T @ t
    return rig_from_cameras(left.cam, right.cam, R, T, unit=unit, source=source)


def calibration_of(camera: _RosCamera) -> CameraCalibration:
    """A camera_info file's camera as a :class:`~canopy_stereo.geometry.frames.CameraCalibration`."""
    w, h = camera.cam.size
    return CameraCalibration(width=w, height=h, K=camera.cam.K, D=camera.cam.D, R=camera.R, P=camera.P,
                             distortion_model=camera.cam.model)


def load_camera_info_yaml(path) -> tuple[CameraCalibration, str]:
    """``(calibration, camera_name)`` of a camera_info YAML file (camera_calibration_parsers'
    format, as ``camera_info_url`` names); :class:`CalibrationError` (one line) when bad."""
    camera = read_camera_info_yaml(path)
    return calibration_of(camera), camera.name


def camera_info_yaml(calibration: CameraCalibration, camera_name: str) -> str:
    """The camera_info YAML text of ``calibration`` (camera_calibration_parsers' layout)."""
    c = calibration

    def block(name, a):
        a = np.asarray(a, np.float64)
        rows, cols = (1, a.size) if a.ndim == 1 else a.shape
        return {name: {"rows": int(rows), "cols": int(cols), "data": [float(v) for v in a.ravel()]}}
    doc = {"image_width": int(c.width), "image_height": int(c.height), "camera_name": str(camera_name),
           **block("camera_matrix", c.K), "distortion_model": c.distortion_model,
           **block("distortion_coefficients", c.D), **block("rectification_matrix", c.R),
           **block("projection_matrix", c.P)}
    return yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=200)


def _camera_of(c: CameraCalibration, name: str, where: str) -> _RosCamera:
    model = c.distortion_model or None
    D = distortion(c.D, model, where, "D")
    model = model or ("plumb_bob" if D.size <= 5 else "rational_polynomial")
    cam = CameraIntrinsics(K=intrinsics(c.K, where, "K"), D=D, model=model,
                           size=image_size(c.width, c.height, where))
    return _RosCamera(cam, rotation(c.R, where, "R"), matrix(c.P, (3, 4), where, "P"), name, where)


def checked_calibration(calibration: CameraCalibration, *, source: str) -> CameraCalibration:
    """``calibration`` (e.g. from a ``CameraInfo`` message) checked as a file's would be
    (camera matrix, rotation, coefficients for the model, size); :class:`CalibrationError`
    naming ``source`` otherwise."""
    return calibration_of(_camera_of(calibration, "", source))


def rig_from_camera_infos(left: CameraCalibration, right: CameraCalibration, *, source: str,
                          unit: str = ROS_UNIT):
    """The rig of a stereo pair's two raw camera infos (a driver's calibration, REP 104; world
    frame = the left camera's optical frame, metres); :class:`CalibrationError` when they are
    not one stereo calibration."""
    return rig_from_ros([_camera_of(left, "left", f"{source} left"), _camera_of(right, "right", f"{source} right")],
                        unit=unit)


def import_ros_yaml(paths, *, unit: str | None = None):
    """``left.yaml right.yaml`` (camera_info YAML) -> rig (unit: metres unless ``unit``)."""
    if len(paths) != 2:
        raise CalibrationError(f"--from ros-yaml takes two files, left.yaml then right.yaml; got {len(paths)}")
    return rig_from_ros([read_camera_info_yaml(p) for p in paths], unit=unit or ROS_UNIT)


def import_ros_ini(paths, *, unit: str | None = None):
    """``ost.txt`` (both cameras) or ``left.ini right.ini`` -> rig (unit: metres unless ``unit``)."""
    if len(paths) not in (1, 2):
        raise CalibrationError(f"--from ros-ini takes ost.txt or left.ini right.ini; got {len(paths)} files")
    cams = [c for p in paths for c in read_ost_ini(p)]
    return rig_from_ros(cams, unit=unit or ROS_UNIT)
