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

Other keys under ``ros__parameters`` (node parameters such as ``method`` or
``H_left``) are preserved in :attr:`Rig.extra`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import yaml

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.camera import validate_projection

#: Metres per world unit for the units a rig file may declare.
UNIT_TO_METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001, "um": 1e-6, "in": 0.0254}


def unit_to_metres(unit: str) -> float:
    """Metres per ``unit`` (``"mm"`` -> 0.001); raises :class:`RigError` if unknown."""
    try:
        return UNIT_TO_METRES[unit]
    except KeyError:
        raise RigError(
            f"unknown world_unit {unit!r}; expected one of {', '.join(UNIT_TO_METRES)}"
        ) from None


def _distortion(value, name: str) -> np.ndarray:
    if value is None:
        return np.zeros(5)
    try:
        d = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise RigError(f"{name} must be a list of numbers") from None
    if d.size not in (4, 5, 8, 12, 14):
        raise RigError(f"{name} must have 4, 5, 8, 12 or 14 coefficients (OpenCV order), got {d.size}")
    if not np.all(np.isfinite(d)):
        raise RigError(f"{name} has non-finite entries")
    return d


@dataclass(frozen=True)
class Rig:
    """A calibrated stereo rig in a world frame.

    Attributes:
        P_left, P_right: (3, 4) projection matrices, world units -> pixels of the
            original (unrectified, undistorted) images.
        image_size: ``(width, height)`` of the original images in pixels.
        world_unit: unit of world coordinates (``"mm"`` for the paper's rig).
        D_left, D_right: OpenCV distortion coefficients (zeros when none).
        extra: other parameters found in the file (kept on save).
    """

    P_left: np.ndarray
    P_right: np.ndarray
    image_size: tuple[int, int]
    world_unit: str = "mm"
    D_left: np.ndarray = field(default_factory=lambda: np.zeros(5))
    D_right: np.ndarray = field(default_factory=lambda: np.zeros(5))
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "P_left", validate_projection(self.P_left, "P_left"))
        object.__setattr__(self, "P_right", validate_projection(self.P_right, "P_right"))
        object.__setattr__(self, "D_left", _distortion(self.D_left, "D_left"))
        object.__setattr__(self, "D_right", _distortion(self.D_right, "D_right"))
        w, h = (int(v) for v in self.image_size)
        if w <= 0 or h <= 0:
            raise RigError(f"image size must be positive, got {w}x{h}")
        object.__setattr__(self, "image_size", (w, h))
        unit_to_metres(self.world_unit)

    @property
    def metres_per_unit(self) -> float:
        """Metres per world unit (0.001 for a rig in millimetres)."""
        return unit_to_metres(self.world_unit)

    @property
    def has_distortion(self) -> bool:
        """True when either camera has non-zero distortion coefficients."""
        return bool(np.any(self.D_left) or np.any(self.D_right))

    @property
    def baseline(self) -> float:
        """Distance between the camera centres, in world units."""
        from canopy_stereo.geometry.camera import camera_centre

        return float(np.linalg.norm(camera_centre(self.P_right) - camera_centre(self.P_left)))

    def with_extra(self, **extra) -> "Rig":
        """A copy with more (or replaced) extra parameters."""
        return replace(self, extra={**self.extra, **extra})

    def to_parameters(self) -> dict:
        """The ``ros__parameters`` mapping of this rig (plain Python types)."""
        params = {
            "world_unit": self.world_unit,
            "image_width": self.image_size[0],
            "image_height": self.image_size[1],
            "P_left": [float(v) for v in self.P_left.ravel()],
            "P_right": [float(v) for v in self.P_right.ravel()],
            "D_left": [float(v) for v in self.D_left],
            "D_right": [float(v) for v in self.D_right],
        }
        for k, v in self.extra.items():
            params.setdefault(k, v)
        return params


def rig_from_parameters(params: dict, source: str = "rig") -> Rig:
    """Build a :class:`Rig` from a ``ros__parameters`` mapping."""
    if not isinstance(params, dict):
        raise RigError(f"{source}: ros__parameters must be a mapping")
    missing = [k for k in ("P_left", "P_right", "image_width", "image_height") if k not in params]
    if missing:
        raise RigError(f"{source}: missing parameter(s) {', '.join(missing)}")
    known = {"world_unit", "image_width", "image_height", "P_left", "P_right", "D_left", "D_right"}
    try:
        return Rig(
            P_left=params["P_left"],
            P_right=params["P_right"],
            image_size=(params["image_width"], params["image_height"]),
            world_unit=str(params.get("world_unit", "mm")),
            D_left=params.get("D_left"),
            D_right=params.get("D_right"),
            extra={k: v for k, v in params.items() if k not in known},
        )
    except RigError as exc:
        raise RigError(f"{source}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise RigError(f"{source}: {exc}") from None


def load_rig(path) -> Rig:
    """Read a rig file (ROS 2 parameter YAML); raises :class:`RigError` on any problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise RigError(f"cannot read rig file {path}: {exc.strerror or exc}") from None
    return rig_from_yaml(text, source=f"rig file {path}")


def rig_from_yaml(text: str, source: str = "rig") -> Rig:
    """Parse the text of a rig file (ROS 2 parameter YAML, e.g. one stored in a bag's
    metadata); ``source`` names it in errors. Raises :class:`RigError` on any problem."""
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RigError(f"{source} is not valid YAML: {exc}") from None
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
