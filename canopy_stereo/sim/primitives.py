"""Analytic scene primitives: leaves, cylinders, spheres, discs, pot frusta, rectangles.

Each primitive is a frozen dataclass in world coordinates (world units) with a
local frame: ``axes`` (3, 3) whose *rows* are the local x, y, z axes expressed
in world coordinates, and an ``origin`` (3,), so that

    p_local = axes @ (p_world - origin),    p_world = axes.T @ p_local + origin.

The ray caster (:mod:`canopy_stereo.sim.raycast`) intersects rays with each
surface in that local frame, where every surface is a quadric or a plane:

=========  ===================================================  =====================
kind       local surface                                        geometry row
=========  ===================================================  =====================
leaf       ``z = droop x^2 + rise x + cup y^2`` inside outline  span, half_width, a, b,
                                                                norm, droop, rise, cup
cylinder   ``x^2 + y^2 = r^2``, ``0 <= z <= h`` (open tube)     r, h
sphere     ``x^2 + y^2 + z^2 = r^2``                            r
disc       ``z = 0``, ``x^2 + y^2 <= r^2``                      r
frustum    ``x^2 + y^2 = (r0 + (r1 - r0) z / h)^2``, ``0..h``   r0, r1, h
rectangle  ``z = 0``, ``|x| <= hx``, ``|y| <= hy`` (inf ok)     hx, hy
=========  ===================================================  =====================

Every primitive can be moved by a similarity ``p -> t + s Q p``
(:meth:`transformed`), which is how scenes built in millimetres in front of a
canonical rig are placed in front of any rig, in its world frame and unit.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import ClassVar

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.sim import leaf as leafgeom
from canopy_stereo.sim.textures import MATERIAL_KINDS, N_MATERIAL_PARAMS

PRIM_LEAF = 0
PRIM_CYLINDER = 1
PRIM_SPHERE = 2
PRIM_DISC = 3
PRIM_FRUSTUM = 4
PRIM_RECTANGLE = 5

#: Number of geometry parameters per primitive row.
N_GEOMETRY_PARAMS = 8

#: Pixel classes of the label images (``labels_left``/``labels_right``).
LABEL_NONE = 0
LABEL_LEAF = 1
LABEL_STEM = 2
LABEL_POT = 3
LABEL_SOIL = 4
LABEL_BACKGROUND = 5
LABEL_FRUIT = 6
#: Objects that are not plants and not containers of one (a watering can, a box, a stake).
LABEL_OBJECT = 7
LABEL_NAMES = {LABEL_NONE: "none", LABEL_LEAF: "leaf", LABEL_STEM: "stem", LABEL_POT: "pot",
               LABEL_SOIL: "soil", LABEL_BACKGROUND: "background", LABEL_FRUIT: "fruit",
               LABEL_OBJECT: "object"}
#: Classes that are part of a plant (the truth of a plant mask).
PLANT_LABELS = (LABEL_LEAF, LABEL_STEM, LABEL_FRUIT)
#: Classes of the things a plant mask must leave out that stand near a plant (distractors).
DISTRACTOR_LABELS = (LABEL_POT, LABEL_SOIL, LABEL_OBJECT)


@dataclass(frozen=True)
class Material:
    """Texture of a surface: a kind name (see :data:`~canopy_stereo.sim.textures.MATERIAL_PARAMS`),
    a seed for its noise and up to six float parameters (lengths in millimetres)."""

    kind: str
    seed: int = 0
    params: tuple = ()

    def __post_init__(self):
        if self.kind not in MATERIAL_KINDS:
            raise CanopyStereoError(f"unknown material {self.kind!r}; "
                                    f"choose one of {', '.join(MATERIAL_KINDS)}")
        if len(self.params) > N_MATERIAL_PARAMS:
            raise CanopyStereoError(f"material {self.kind!r} takes at most {N_MATERIAL_PARAMS} "
                                    f"parameters, got {len(self.params)}")

    def row(self) -> np.ndarray:
        """(2 + N_MATERIAL_PARAMS,) float row: kind code, seed, parameters (zero padded)."""
        out = np.zeros(2 + N_MATERIAL_PARAMS)
        out[0] = MATERIAL_KINDS[self.kind]
        out[1] = self.seed % 1_000_003
        out[2:2 + len(self.params)] = self.params
        return out


def frame_from_z(z, hint=None) -> np.ndarray:
    """Right-handed orthonormal axes (rows x, y, z) with the given z axis.

    ``hint`` (3,) is a direction the x axis should lean towards; by default the
    world axis least aligned with ``z``.
    """
    z = np.asarray(z, np.float64)
    z = z / np.linalg.norm(z)
    if hint is None:
        hint = np.eye(3)[int(np.argmin(np.abs(z)))]
    hint = np.asarray(hint, np.float64)
    x = hint - (hint @ z) * z
    if np.linalg.norm(x) < 1e-9:
        x = np.eye(3)[int(np.argmin(np.abs(z)))]
        x = x - (x @ z) * z
    x /= np.linalg.norm(x)
    return np.vstack([x, np.cross(z, x), z])


def frame_from_xz(x, z_hint) -> np.ndarray:
    """Right-handed axes (rows): x exactly along ``x``, z as close as possible to ``z_hint``."""
    x = np.asarray(x, np.float64)
    x = x / np.linalg.norm(x)
    z = np.asarray(z_hint, np.float64) - (np.asarray(z_hint, np.float64) @ x) * x
    nz = np.linalg.norm(z)
    if nz < 1e-9:
        raise CanopyStereoError("leaf normal hint is parallel to its midrib")
    z /= nz
    return np.vstack([x, np.cross(z, x), z])


def _move_point(p, Q, t, s):
    return np.asarray(t, np.float64) + s * (np.asarray(Q) @ np.asarray(p, np.float64))


def _move_axes(axes, Q):
    return np.asarray(axes, np.float64) @ np.asarray(Q, np.float64).T


@dataclass(frozen=True)
class Leaf:
    """A leaf blade (see :mod:`canopy_stereo.sim.leaf` for the surface and outline).

    Attributes:
        leaf_id: positive id written to the leaf-id images.
        base: (3,) world position of the blade base (petiole attachment).
        axes: (3, 3) rows: midrib reference direction x (base -> tip), across y,
            upper normal z, in world coordinates.
        span: extent of the blade along x (world units).
        half_width: widest half-width in the frame (world units).
        base_exponent, tip_exponent: outline exponents ``a``, ``b``.
        droop, rise, cup: surface coefficients (``1/unit``, slope, ``1/unit``).
        material: leaf material (``croton``, ``citrus`` or ``seedling``).
        name: optional name (``"leaf1"`` for the paper's first marked leaf).
        marked: True for the leaves whose dimensions a test or user measures.
    """

    leaf_id: int
    base: np.ndarray
    axes: np.ndarray
    span: float
    half_width: float
    material: Material
    base_exponent: float = 0.6
    tip_exponent: float = 0.8
    droop: float = 0.0
    rise: float = 0.0
    cup: float = 0.0
    name: str = ""
    marked: bool = False
    label: int = LABEL_LEAF
    kind: ClassVar[int] = PRIM_LEAF

    def __post_init__(self):
        object.__setattr__(self, "base", np.asarray(self.base, np.float64).reshape(3))
        object.__setattr__(self, "axes", np.asarray(self.axes, np.float64).reshape(3, 3))
        if self.leaf_id <= 0:
            raise CanopyStereoError(f"leaf ids must be positive, got {self.leaf_id}")
        if self.span <= 0 or self.half_width <= 0:
            raise CanopyStereoError("leaf span and half-width must be positive")

    @classmethod
    def with_dimensions(cls, leaf_id: int, base, midrib, normal_hint, length: float, width: float,
                        material: Material, *, droop: float = 0.0, rise: float = 0.0,
                        cup: float = 0.0, **kwargs) -> Leaf:
        """A leaf whose true (arc) length and width are exactly ``length`` and ``width``.

        ``midrib`` is the frame x direction (base -> tip), ``normal_hint`` the
        direction the upper side should face (made orthogonal to ``midrib``).
        """
        span = leafgeom.solve_span(length, droop, rise)
        half_width = leafgeom.solve_half_width(width, cup)
        return cls(leaf_id=leaf_id, base=base, axes=frame_from_xz(midrib, normal_hint), span=span,
                   half_width=half_width, material=material, droop=droop, rise=rise, cup=cup,
                   **kwargs)

    # ---------------------------------------------------------------- renderer rows
    @property
    def origin(self) -> np.ndarray:
        return self.base

    def geometry(self) -> np.ndarray:
        return np.array([self.span, self.half_width, self.base_exponent, self.tip_exponent,
                         leafgeom.outline_norm(self.base_exponent, self.tip_exponent),
                         self.droop, self.rise, self.cup])

    def local_bounds(self):
        return leafgeom.blade_bounds(self.span, self.half_width, self.droop, self.rise, self.cup)

    def transformed(self, Q, t, s: float) -> Leaf:
        return replace(self, base=_move_point(self.base, Q, t, s), axes=_move_axes(self.axes, Q),
                       span=self.span * s, half_width=self.half_width * s, droop=self.droop / s,
                       cup=self.cup / s)

    def rotated_about_base(self, R) -> Leaf:
        """The leaf turned by the rotation matrix ``R`` (3, 3) about its base point."""
        return replace(self, axes=self.axes @ np.asarray(R, np.float64).T)

    # ---------------------------------------------------------------- truth
    def to_world(self, p_local) -> np.ndarray:
        """Blade-frame points (N, 3) -> world points (N, 3)."""
        return np.asarray(p_local, np.float64).reshape(-1, 3) @ self.axes + self.base

    def _blade_point(self, x, y):
        z = leafgeom.surface_height(x, y, self.droop, self.rise, self.cup)
        return self.to_world(np.array([[x, y, float(z)]]))[0]

    def surface_points(self, n_along: int = 80, n_across: int = 21) -> np.ndarray:
        """World points (N, 3) on the blade: a grid in (midrib position, relative
        position across) that includes points just inside the outline."""
        s = (np.arange(n_along) + 0.5) / n_along
        rel = np.linspace(-0.999, 0.999, n_across)
        hw = leafgeom.half_width_at(s, self.half_width, self.base_exponent, self.tip_exponent)
        x = np.repeat(s * self.span, n_across)
        y = (hw[:, None] * rel[None, :]).ravel()
        z = leafgeom.surface_height(x, y, self.droop, self.rise, self.cup)
        return self.to_world(np.column_stack([x, y, z]))

    @property
    def widest_x(self) -> float:
        """Frame x of the widest cross-section."""
        return self.span * leafgeom.outline_peak(self.base_exponent, self.tip_exponent)

    @property
    def tip(self) -> np.ndarray:
        """(3,) world position of the leaf tip."""
        return self._blade_point(self.span, 0.0)

    def width_endpoints(self) -> tuple[np.ndarray, np.ndarray]:
        """World positions (3,) of the two blade edges of the widest cross-section."""
        x = self.widest_x
        return self._blade_point(x, -self.half_width), self._blade_point(x, self.half_width)

    @property
    def length(self) -> float:
        """True length: midrib arc length base -> tip (world units)."""
        return leafgeom.midrib_length(self.span, self.droop, self.rise)

    @property
    def width(self) -> float:
        """True width: arc length across the widest section (world units)."""
        return leafgeom.cross_width(self.half_width, self.cup)

    @property
    def length_chord(self) -> float:
        """Straight distance base -> tip (world units)."""
        return float(np.linalg.norm(self.tip - self.base))

    @property
    def width_chord(self) -> float:
        """Straight distance between the edges of the widest section (world units)."""
        a, b = self.width_endpoints()
        return float(np.linalg.norm(b - a))

    @property
    def area(self) -> float:
        """One-sided area of the curved blade (world units squared)."""
        return leafgeom.surface_area(self.span, self.half_width, self.base_exponent,
                                     self.tip_exponent, self.droop, self.rise, self.cup)

    def truth(self) -> dict:
        """JSON-ready description: id, dimensions and pose (world frame and units)."""
        w0, w1 = self.width_endpoints()
        return {
            "id": int(self.leaf_id), "name": self.name, "marked": bool(self.marked),
            "material": self.material.kind,
            "length": self.length, "width": self.width,
            "length_chord": self.length_chord, "width_chord": self.width_chord,
            "area": self.area,
            "pose": {"base": self.base.tolist(), "tip": self.tip.tolist(),
                     "width_endpoints": [w0.tolist(), w1.tolist()],
                     "axes": self.axes.tolist()},
            "shape": {"span": self.span, "half_width": self.half_width,
                      "base_exponent": self.base_exponent, "tip_exponent": self.tip_exponent,
                      "droop": self.droop, "rise": self.rise, "cup": self.cup},
        }


@dataclass(frozen=True)
class Cylinder:
    """An open tube of ``radius`` from ``start`` to ``end`` (stems, petioles, branches)."""

    start: np.ndarray
    end: np.ndarray
    radius: float
    material: Material
    label: int = LABEL_STEM
    kind: ClassVar[int] = PRIM_CYLINDER

    def __post_init__(self):
        object.__setattr__(self, "start", np.asarray(self.start, np.float64).reshape(3))
        object.__setattr__(self, "end", np.asarray(self.end, np.float64).reshape(3))
        if self.length <= 0 or self.radius <= 0:
            raise CanopyStereoError("a cylinder needs distinct end points and a positive radius")

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.end - self.start))

    @property
    def origin(self) -> np.ndarray:
        return self.start

    @property
    def axes(self) -> np.ndarray:
        return frame_from_z(self.end - self.start)

    def geometry(self) -> np.ndarray:
        return np.array([self.radius, self.length])

    def local_bounds(self):
        r = self.radius
        return np.array([-r, -r, 0.0]), np.array([r, r, self.length])

    def transformed(self, Q, t, s: float) -> Cylinder:
        return replace(self, start=_move_point(self.start, Q, t, s),
                       end=_move_point(self.end, Q, t, s), radius=self.radius * s)


@dataclass(frozen=True)
class Sphere:
    """A sphere (fruit, stem joints)."""

    centre: np.ndarray
    radius: float
    material: Material
    label: int = LABEL_FRUIT
    kind: ClassVar[int] = PRIM_SPHERE

    def __post_init__(self):
        object.__setattr__(self, "centre", np.asarray(self.centre, np.float64).reshape(3))

    @property
    def origin(self) -> np.ndarray:
        return self.centre

    @property
    def axes(self) -> np.ndarray:
        return np.eye(3)

    def geometry(self) -> np.ndarray:
        return np.array([self.radius])

    def local_bounds(self):
        return np.full(3, -self.radius), np.full(3, self.radius)

    def transformed(self, Q, t, s: float) -> Sphere:
        return replace(self, centre=_move_point(self.centre, Q, t, s), radius=self.radius * s)


@dataclass(frozen=True)
class Disc:
    """A flat disc of ``radius`` around ``centre`` facing ``normal`` (soil surface)."""

    centre: np.ndarray
    normal: np.ndarray
    radius: float
    material: Material
    label: int = LABEL_SOIL
    kind: ClassVar[int] = PRIM_DISC

    def __post_init__(self):
        object.__setattr__(self, "centre", np.asarray(self.centre, np.float64).reshape(3))
        n = np.asarray(self.normal, np.float64).reshape(3)
        object.__setattr__(self, "normal", n / np.linalg.norm(n))

    @property
    def origin(self) -> np.ndarray:
        return self.centre

    @property
    def axes(self) -> np.ndarray:
        return frame_from_z(self.normal)

    def geometry(self) -> np.ndarray:
        return np.array([self.radius])

    def local_bounds(self):
        r = self.radius
        return np.array([-r, -r, 0.0]), np.array([r, r, 0.0])

    def transformed(self, Q, t, s: float) -> Disc:
        return replace(self, centre=_move_point(self.centre, Q, t, s),
                       normal=np.asarray(Q) @ self.normal, radius=self.radius * s)


@dataclass(frozen=True)
class Frustum:
    """A conical pot wall: radius ``radius_base`` at ``base`` to ``radius_top`` at
    ``base + height * axis`` (open at both ends)."""

    base: np.ndarray
    axis: np.ndarray
    height: float
    radius_base: float
    radius_top: float
    material: Material
    label: int = LABEL_POT
    kind: ClassVar[int] = PRIM_FRUSTUM

    def __post_init__(self):
        object.__setattr__(self, "base", np.asarray(self.base, np.float64).reshape(3))
        a = np.asarray(self.axis, np.float64).reshape(3)
        object.__setattr__(self, "axis", a / np.linalg.norm(a))

    @property
    def origin(self) -> np.ndarray:
        return self.base

    @property
    def axes(self) -> np.ndarray:
        return frame_from_z(self.axis)

    def geometry(self) -> np.ndarray:
        return np.array([self.radius_base, self.radius_top, self.height])

    def local_bounds(self):
        r = max(self.radius_base, self.radius_top)
        return np.array([-r, -r, 0.0]), np.array([r, r, self.height])

    def transformed(self, Q, t, s: float) -> Frustum:
        return replace(self, base=_move_point(self.base, Q, t, s), axis=np.asarray(Q) @ self.axis,
                       height=self.height * s, radius_base=self.radius_base * s,
                       radius_top=self.radius_top * s)


@dataclass(frozen=True)
class Rectangle:
    """A flat rectangle (infinite when ``half_x``/``half_y`` are ``inf``): backgrounds, trays.

    ``axes`` rows are its x and y edge directions and its normal.
    """

    centre: np.ndarray
    axes: np.ndarray
    half_x: float
    half_y: float
    material: Material
    label: int = LABEL_BACKGROUND
    kind: ClassVar[int] = PRIM_RECTANGLE

    def __post_init__(self):
        object.__setattr__(self, "centre", np.asarray(self.centre, np.float64).reshape(3))
        object.__setattr__(self, "axes", np.asarray(self.axes, np.float64).reshape(3, 3))

    @property
    def origin(self) -> np.ndarray:
        return self.centre

    @property
    def normal(self) -> np.ndarray:
        return self.axes[2].copy()

    def geometry(self) -> np.ndarray:
        return np.array([self.half_x, self.half_y])

    def local_bounds(self):
        hx, hy = self.half_x, self.half_y
        return np.array([-hx, -hy, 0.0]), np.array([hx, hy, 0.0])

    def transformed(self, Q, t, s: float) -> Rectangle:
        return replace(self, centre=_move_point(self.centre, Q, t, s),
                       axes=_move_axes(self.axes, Q), half_x=self.half_x * s,
                       half_y=self.half_y * s)


Primitive = Leaf | Cylinder | Sphere | Disc | Frustum | Rectangle


def local_corners(prim) -> np.ndarray:
    """(8, 3) world corners of the primitive's local bounding box (may be inf)."""
    lo, hi = prim.local_bounds()
    corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1],
                         hi[2] if i & 4 else lo[2]] for i in range(8)])
    with np.errstate(invalid="ignore"):
        return corners @ prim.axes + prim.origin


__all__ = ["Cylinder", "DISTRACTOR_LABELS", "Disc", "Frustum", "LABEL_NAMES", "PLANT_LABELS", "Leaf", "Material",
           "Primitive", "Rectangle", "Sphere", "frame_from_xz", "frame_from_z", "local_corners"]
