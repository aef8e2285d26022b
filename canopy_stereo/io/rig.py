"""Rig files: the stereo camera matrices as a ROS 2 parameter file.

One format serves the CLI and the ROS nodes::

    /**:
      ros__parameters:
        world_unit: mm            # unit of the world frame the P matrices map from
        image_width: 640
        image_height: 480
        P_left:  [12 numbers, row-major 3x4]
        P_right: [12 numbers, row-major 3x4]
        D_left:  [k1, k2, p1, p2, k3]   # optional lens distortion (OpenCV order)
        D_right: [k1, k2, p1, p2, k3]
        distortion_model: equidistant  # optional: plumb_bob / rational_polynomial (OpenCV's
                                       # model, 4-14 coefficients, the default) or equidistant
                                       # (fisheye, [k1, k2, k3, k4])

Other keys under ``ros__parameters`` (node parameters such as ``method`` or
``H_left``) are preserved in :attr:`Rig.extra`; a key the package does not know
(:mod:`canopy_stereo.io.rig_keys`, e.g. the typo ``disp_mx``) is an error naming the
nearest valid key. The :class:`Rig` itself (and the
world units) is :mod:`canopy_stereo.geometry.rig`; this module reads and writes it.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.rig import UNIT_TO_METRES, Rig, unit_to_metres
from canopy_stereo.io.rig_keys import check_rig_keys
from canopy_stereo.io.yaml_files import read_text_file, yaml_error_line

__all__ = ["UNIT_TO_METRES", "Rig", "load_rig", "rig_from_parameters", "rig_from_yaml", "rig_to_yaml",
           "save_rig", "unit_to_metres"]


def rig_from_parameters(params: dict, source: str = "rig") -> Rig:
    """Build a :class:`Rig` from a ``ros__parameters`` mapping."""
    if not isinstance(params, dict):
        raise RigError(f"{source}: ros__parameters must be a mapping")
    check_rig_keys(params, source=source)  # a typo (disp_mx) is an error, not a silent default
    missing = [k for k in ("P_left", "P_right", "image_width", "image_height") if k not in params]
    if missing:
        raise RigError(f"{source}: missing parameter(s) {', '.join(missing)}")
    known = {"world_unit", "image_width", "image_height", "P_left", "P_right", "D_left", "D_right",
             "distortion_model"}
    for name in ("image_width", "image_height", "P_left", "P_right", "D_left", "D_right"):
        _check_numbers(params.get(name), name, source)
    try:
        return Rig(
            P_left=params["P_left"],
            P_right=params["P_right"],
            image_size=(params["image_width"], params["image_height"]),
            world_unit=str(params.get("world_unit", "mm")),
            D_left=params.get("D_left"),  # type: ignore[arg-type]  # None: no distortion (Rig: zeros)
            D_right=params.get("D_right"),  # type: ignore[arg-type]
            distortion_model=params.get("distortion_model") or None,
            extra={k: v for k, v in params.items() if k not in known},
        )
    except RigError as exc:
        raise RigError(f"{source}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise RigError(f"{source}: {exc}") from None


def _check_numbers(value, name: str, source: str) -> None:
    """Refuse a number written as a string (``image_width: "640"``): the schema says number, and
    a ROS node given the same file gets a string parameter, so every entry point refuses it."""
    items = value if isinstance(value, (list, tuple)) else [value]
    for item in items:
        if isinstance(item, (str, bytes, bool)):
            raise RigError(f"{source}: {name} must be {'numbers' if items is value else 'a number'}, "
                           f"got {item!r} (write it without quotes)")


def load_rig(path) -> Rig:
    """Read a rig file (ROS 2 parameter YAML); raises :class:`RigError` on any problem."""
    path = Path(path)
    text = read_text_file(path, "rig file", error=RigError)
    return rig_from_yaml(text, source=f"rig file {path}")


def rig_from_yaml(text: str, source: str = "rig") -> Rig:
    """Parse the text of a rig file (ROS 2 parameter YAML, e.g. one stored in a bag's
    metadata); ``source`` names it in errors. Raises :class:`RigError` on any problem."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RigError(f"{source} is not valid YAML: {yaml_error_line(exc)}") from None
    if not isinstance(doc, dict):
        raise RigError(f"{source} is not a ROS 2 parameter file (expected a mapping)")
    params = None
    for node_params in doc.values():
        if isinstance(node_params, dict) and "ros__parameters" in node_params:
            params = node_params["ros__parameters"]
            break
    if params is None:
        raise RigError(f"{source} has no '<node>: ros__parameters:' section")
    return rig_from_parameters(params, source=source.removeprefix("rig file "))


def rig_to_yaml(rig: Rig, comment: str | None = None) -> str:
    """The text of ``rig``'s rig file (see :func:`save_rig`)."""
    body = yaml.safe_dump({"/**": {"ros__parameters": rig.to_parameters()}},
                          sort_keys=False, default_flow_style=None, width=200)
    header = ""
    if comment:
        header = "".join(f"# {line}\n" for line in comment.splitlines())
    return header + body


def save_rig(rig: Rig, path, *, comment: str | None = None) -> Path:
    """Write ``rig`` as a ROS 2 parameter file usable by every node (``/**`` wildcard)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(rig_to_yaml(rig, comment), encoding="utf-8")
    return path
