"""A calibrated stereo rig: two projection matrices, lens distortion and image size in a world frame.

Files of rigs (ROS 2 parameter YAML) are read and written by :mod:`canopy_stereo.io.rig`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.camera import camera_centre, validate_projection
from canopy_stereo.geometry.distortion import DISTORTION_MODELS, check_distortion, default_distortion_model

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


def _distortion(value, model: str, name: str) -> np.ndarray:
    d = check_distortion(value, model, name) if value is not None else np.zeros(0)
    return d if d.size else np.zeros(4 if model == "equidistant" else 5)


@dataclass(frozen=True)
class Rig:
    """A calibrated stereo rig in a world frame.

    Attributes:
        P_left, P_right: (3, 4) projection matrices, world units -> pixels of the
            original (unrectified, undistorted) images.
        image_size: ``(width, height)`` of the original images in pixels.
        world_unit: unit of world coordinates (``"mm"`` for the paper's rig).
        D_left, D_right: distortion coefficients of ``distortion_model`` (zeros when none).
        extra: other parameters found in the file (kept on save).
        distortion_model: both cameras' lens model (REP 104 name, see
            :mod:`canopy_stereo.geometry.distortion`): ``plumb_bob`` or
            ``rational_polynomial`` (OpenCV's standard model, by the coefficients' count) or
            ``equidistant`` (fisheye); None = from the count.
    """

    P_left: np.ndarray
    P_right: np.ndarray
    image_size: tuple[int, int]
    world_unit: str = "mm"
    D_left: np.ndarray = field(default_factory=lambda: np.zeros(5))
    D_right: np.ndarray = field(default_factory=lambda: np.zeros(5))
    extra: dict = field(default_factory=dict)
    distortion_model: str | None = None

    def __post_init__(self):
        model = self.distortion_model
        if model is None or model in ("plumb_bob", "rational_polynomial"):
            sizes = [np.asarray(d).size for d in (self.D_left, self.D_right) if d is not None]
            model = default_distortion_model(np.zeros(max(sizes, default=5)))
        if model not in DISTORTION_MODELS:
            raise RigError(f"unknown distortion_model {model!r}; expected one of {', '.join(DISTORTION_MODELS)}")
        object.__setattr__(self, "distortion_model", model)
        object.__setattr__(self, "P_left", validate_projection(self.P_left, "P_left"))
        object.__setattr__(self, "P_right", validate_projection(self.P_right, "P_right"))
        object.__setattr__(self, "D_left", _distortion(self.D_left, model, "D_left"))
        object.__setattr__(self, "D_right", _distortion(self.D_right, model, "D_right"))
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
        return float(np.linalg.norm(camera_centre(self.P_right) - camera_centre(self.P_left)))

    def with_extra(self, **extra) -> Rig:
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
        if self.distortion_model == "equidistant":
            params["distortion_model"] = self.distortion_model
        for k, v in self.extra.items():
            params.setdefault(k, v)
        return params
