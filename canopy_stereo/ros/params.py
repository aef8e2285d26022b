"""Node parameters shared by the nodes that need the rig.

A rig file (:mod:`canopy_stereo.io.rig`) is a ROS 2 parameter file under the
``/**`` wildcard, so ``--ros-args --params-file config/paper_rig.yaml`` gives
every node ``P_left``, ``P_right``, ``D_left``, ``D_right``, ``image_width``,
``image_height`` and ``world_unit`` (plus extras such as ``method``,
``H_left``/``H_right``, ``disp_min``/``disp_max``). Alternatively the
parameter ``rig_file`` names such a file. These parameters are read-only:
the rectification maps are built once at start-up.
"""
from __future__ import annotations

import numpy as np
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.parameter import Parameter

from canopy_stereo.errors import CanopyStereoError, RigError
from canopy_stereo.geometry.rectification import Rectification
from canopy_stereo.geometry.rig_rectification import rectification_for_rig
from canopy_stereo.io.rig import Rig, load_rig, rig_from_parameters
from canopy_stereo.io.yaml_files import read_yaml_file


def parameter_files(argv) -> list[str]:
    """The ``--params-file`` paths of a command line's ``--ros-args`` sections, in order."""
    files, in_ros, it = [], False, iter(argv or [])
    for token in it:
        if token == "--ros-args":
            in_ros = True
        elif token == "--":
            in_ros = False
        elif in_ros and token == "--params-file":
            files.append(next(it, ""))
    return files


def check_parameter_file(path) -> None:
    """Check that ``path`` is a readable UTF-8 ROS 2 parameter file (``<node>: ros__parameters:
    {...}``, nodes possibly under namespaces) before rcl parses it; raises
    :class:`CanopyStereoError` with one line naming the file and the problem. (rcl's own
    parser would fail with a multi-line ``RCLError`` and its own log line.)"""
    doc = read_yaml_file(path, "parameter file")
    if doc is None:
        return  # empty: rcl accepts it (no parameters)
    _check_parameter_tree(doc, path, ())


def _check_parameter_tree(doc, path, keys: tuple) -> None:
    where = "/".join(str(k) for k in keys) or "the top level"
    if not isinstance(doc, dict):
        raise CanopyStereoError(
            f"parameter file {path} is not a ROS 2 parameter file: {where} is a {_yaml_kind(doc)}, "
            "expected '<node name>: ros__parameters: {name: value, ...}'")
    for key, value in doc.items():
        if key == "ros__parameters":
            if not isinstance(value, dict):
                raise CanopyStereoError(f"parameter file {path}: ros__parameters of {where} is a "
                                        f"{_yaml_kind(value)}, expected a mapping of parameter names to values")
            continue
        _check_parameter_tree(value, path, keys + (key,))


def _yaml_kind(value) -> str:
    if isinstance(value, list):
        return "list"
    if value is None:
        return "empty value"
    return f"{type(value).__name__} ({value!r:.40})"



def number_descriptor(description: str, *, minimum, maximum, step=0, integer: bool,
                      read_only: bool = False, dynamic: bool = False) -> ParameterDescriptor:
    """Descriptor of a numeric parameter with its ``IntegerRange``/``FloatingPointRange``
    (``ros2 param describe``, rqt_reconfigure and the parameter services enforce it)."""
    d = ParameterDescriptor(description=description, read_only=read_only, dynamic_typing=dynamic)
    if integer:
        if not dynamic:
            d.type = ParameterType.PARAMETER_INTEGER
        d.integer_range = [IntegerRange(from_value=int(minimum), to_value=int(maximum), step=int(step))]
    else:
        if not dynamic:
            d.type = ParameterType.PARAMETER_DOUBLE
        d.floating_point_range = [FloatingPointRange(from_value=float(minimum), to_value=float(maximum),
                                                     step=float(step))]
    return d


def text_descriptor(description: str, *, choices=None, read_only: bool = False) -> ParameterDescriptor:
    """Descriptor of a string parameter; ``choices`` are appended to the description."""
    if choices:
        description = f"{description} ({' | '.join(choices)})"
    return ParameterDescriptor(description=description, read_only=read_only,
                               type=ParameterType.PARAMETER_STRING)


def flag_descriptor(description: str, *, read_only: bool = False) -> ParameterDescriptor:
    """Descriptor of a boolean parameter."""
    return ParameterDescriptor(description=description, read_only=read_only, type=ParameterType.PARAMETER_BOOL)


#: rig parameter name -> description
RIG_PARAMETERS = {
    "P_left": "left 3x4 projection matrix, world -> original pixels (12 numbers, row-major)",
    "P_right": "right 3x4 projection matrix (12 numbers, row-major)",
    "D_left": "left distortion coefficients (OpenCV order, or k1-k4 for equidistant), optional",
    "D_right": "right distortion coefficients (OpenCV order, or k1-k4 for equidistant), optional",
    "distortion_model": "lens model of D_left/D_right: plumb_bob | rational_polynomial | equidistant "
                        "(empty = OpenCV's model, by the number of coefficients)",
    "image_width": "width of the raw images in pixels",
    "image_height": "height of the raw images in pixels",
    "world_unit": "unit of the world frame of P (m, cm, mm, ...)",
}



def _read_only(description: str, dynamic: bool = True) -> ParameterDescriptor:
    return ParameterDescriptor(description=description, read_only=True, dynamic_typing=dynamic)


def declare_rig_parameters(node) -> None:
    """Declare ``rig_file``, the rig parameters, ``method`` and ``H_left``/``H_right``."""
    node.declare_parameter("rig_file", "", _read_only("rig file (ROS 2 parameter YAML); "
                                                      "used when P_left/P_right are not set"))
    for name, desc in RIG_PARAMETERS.items():
        if name in ("image_width", "image_height"):
            descriptor = number_descriptor(desc, minimum=1, maximum=65535, integer=True, read_only=True,
                                           dynamic=True)
        else:
            descriptor = _read_only(desc)
        node.declare_parameter(name, None, descriptor)
    node.declare_parameter("method", "", _read_only(
        "rectification: fusiello (calibrated) or hartley (H_left/H_right from "
        "canopy-stereo rectify --method hartley); empty = the rig's, else fusiello"))
    node.declare_parameter("H_left", None, _read_only("hartley: left rectifying homography (9 numbers); "
                                                      "unset = the rig file's"))
    node.declare_parameter("H_right", None, _read_only("hartley: right rectifying homography (9 numbers); "
                                                       "unset = the rig file's"))


def _value(node, name):
    value = node.get_parameter(name).value
    if value is None:
        return None
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        value = list(value)
        return value if value else None
    return value


def rig_from_node(node) -> Rig:
    """The :class:`Rig` described by the node's parameters (raises :class:`RigError`)."""
    params = {name: _value(node, name) for name in RIG_PARAMETERS}
    params = {k: v for k, v in params.items() if v is not None}
    rig_file = node.get_parameter("rig_file").value
    if "P_left" not in params and "P_right" not in params:
        if not rig_file:
            raise RigError("no rig: pass a rig file with --params-file (P_left, P_right, "
                           "image_width, image_height) or set the parameter rig_file")
        rig = load_rig(rig_file)
        return rig
    return rig_from_parameters(params, source=f"node {node.get_name()} parameters")


def rig_given(node) -> bool:
    """True when the node was given a rig (``rig_file`` or any rig parameter), so that a rig
    that cannot be built is an error rather than "no rig"."""
    return bool(node.get_parameter("rig_file").value) or any(
        _value(node, name) is not None for name in RIG_PARAMETERS)


def rectification_from_node(node, rig: Rig) -> Rectification:
    """The rig's rectification (:func:`~canopy_stereo.geometry.rig_rectification.rectification_for_rig`):
    the parameters ``method`` and ``H_left``/``H_right`` when set (a rig file given with
    ``--params-file`` sets them), else the ``rig_file``'s, else Fusiello."""
    try:
        return rectification_for_rig(rig, method=node.get_parameter("method").value or None,
                                     H_left=_value(node, "H_left"), H_right=_value(node, "H_right"))
    except RigError as exc:
        from_file = _value(node, "P_left") is None and _value(node, "P_right") is None
        source = (f"rig file {node.get_parameter('rig_file').value}" if from_file
                  else f"node {node.get_name()} parameters")
        raise RigError(f"{source}: {exc}") from None


def rectification_for(rig: Rig, method: str = "fusiello", *, H_left=None, H_right=None) -> Rectification:
    """Fusiello rectification of ``rig``, or the Hartley one given its two homographies
    (or the rig's); see :func:`~canopy_stereo.geometry.rig_rectification.rectification_for_rig`."""
    return rectification_for_rig(rig, method=method, H_left=H_left, H_right=H_right)


def rig_parameter_overrides(rig: Rig, include_extra: bool = True) -> list[Parameter]:
    """The rig as ``rclpy`` parameters (for nodes created in-process)."""
    params = rig.to_parameters() if include_extra else {
        k: v for k, v in rig.to_parameters().items() if k in RIG_PARAMETERS}
    return parameters_from_dict(params)


def flatten_parameters(values: dict, prefix: str = "") -> dict:
    """``{"elas": {"subpixel": True}}`` -> ``{"elas.subpixel": True}`` (ROS parameter names)."""
    flat = {}
    for name, value in values.items():
        key = f"{prefix}{name}"
        if isinstance(value, dict):
            flat.update(flatten_parameters(value, key + "."))
        else:
            flat[key] = value
    return flat


def parameters_from_dict(values: dict) -> list[Parameter]:
    """``rclpy`` parameters from plain Python values (nested mappings become dotted
    names, lists of numbers double arrays; empty lists are skipped)."""
    out = []
    for name, value in flatten_parameters(values).items():
        if isinstance(value, (list, tuple)) and value and all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            value = [float(v) for v in value]
        if isinstance(value, (list, tuple)) and not value:
            continue
        if isinstance(value, np.generic):
            value = value.item()
        out.append(Parameter(name, value=value))
    return out
