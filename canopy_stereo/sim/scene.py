"""Scene model: primitives, lighting, a background at a known distance, and breeze.

A :class:`Scene` holds its primitives in their rest pose plus a frame number;
:meth:`Scene.posed` gives the primitives at that frame, in which every leaf
with a :class:`Breeze` is turned about its base by a small, smooth angle (a
gentle breeze). Frame 0 is the rest pose.

Scenes are built in millimetres in a *rig anchor frame* (origin between the
two cameras, z along their mean viewing direction, y about image-down; see
:func:`rig_anchor`) and placed in front of a particular rig, in its world
frame and unit, with :meth:`Scene.transformed`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import decompose_projection
from canopy_stereo.sim.primitives import Cylinder, Leaf, Rectangle, Sphere
from canopy_stereo.sim.raycast import PackedScene


def axis_angle_matrix(axis, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) of ``angle`` radians about the unit ``axis`` (Rodrigues)."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


@dataclass(frozen=True)
class Breeze:
    """Swaying of one leaf about its base: at frame ``f`` the leaf is turned by
    ``amplitude * (sin(2 pi f / period + phase) - sin(phase))`` radians about
    ``axis`` (world direction), so frame 0 is the rest pose."""

    axis: np.ndarray
    amplitude: float
    phase: float
    period: float

    def angle(self, frame: int) -> float:
        """Rotation angle (radians) at ``frame``."""
        w = 2 * np.pi / self.period
        return float(self.amplitude * (np.sin(w * frame + self.phase) - np.sin(self.phase)))


@dataclass(frozen=True)
class PlantSpec:
    """One plant of a scene, for per-plant truth (instances and heights).

    Attributes:
        name: plant name (``"plant"``, ``"seedling 12"``, ...).
        leaf_ids: ids of its leaves.
        part_indices: indices into the scene's ``primitives`` of its other parts
            (stems, petioles: cylinders and spheres).
        reference_point: (3,) world point on its reference surface (the centre of the
            pot rim, or the soil it grows from).
        up: (3,) world unit vector "up" (away from the surface the plant stands on).
        reference: ``"pot_rim"`` or ``"soil"``: what ``reference_point`` lies on.
    """

    name: str
    leaf_ids: tuple
    part_indices: tuple
    reference_point: np.ndarray
    up: np.ndarray
    reference: str = "pot_rim"

    def transformed(self, Q, t, s: float) -> PlantSpec:
        Q = np.asarray(Q, np.float64)
        return replace(self, reference_point=np.asarray(t, np.float64) + s * Q @ self.reference_point,
                       up=Q @ np.asarray(self.up, np.float64))

    def top(self, primitives) -> float:
        """Highest point of the plant along ``up`` (world units, the posed ``primitives``),
        from its leaves' dense surface samples and its stems' exact tops."""
        up = np.asarray(self.up, np.float64)
        ids = set(self.leaf_ids)
        tops = [float(np.max(p.surface_points(200, 41) @ up)) for p in primitives
                if isinstance(p, Leaf) and p.leaf_id in ids]
        for i in self.part_indices:
            p = primitives[i]
            if isinstance(p, Cylinder):
                a = (p.end - p.start) / p.length
                side = p.radius * np.sqrt(max(0.0, 1.0 - float(a @ up) ** 2))
                tops.append(max(float(p.start @ up), float(p.end @ up)) + side)
            elif isinstance(p, Sphere):
                tops.append(float(p.centre @ up) + p.radius)
        return max(tops)


@dataclass(frozen=True)
class Scene:
    """A renderable scene.

    Attributes:
        name: scene name (``croton``, ``citrus_branch``, ``seedling_tray``, ...).
        seed: random seed it was built from.
        primitives: rest-pose primitives (world coordinates, ``world_unit``).
        background: the background plane (also one of ``primitives``).
        light: (3,) unit direction towards the (directional) light.
        ambient, diffuse: shading weights (``ambient + diffuse * |n . light|``).
        breeze: leaf id -> :class:`Breeze`.
        frame: frame number (0 = rest pose).
        world_unit: unit of all coordinates and lengths.
        anchor_origin, anchor_axes: the rig anchor frame (origin (3,), axes rows
            (3, 3)) the scene was placed in; the background distance is measured
            from ``anchor_origin`` along ``anchor_axes[2]``.
        plants: :class:`PlantSpec` of each plant, numbered 1.. in this order (left to
            right in the image); empty for scenes without per-plant truth.
    """

    name: str
    seed: int
    primitives: tuple
    background: Rectangle
    light: np.ndarray
    ambient: float = 0.35
    diffuse: float = 0.65
    breeze: dict = field(default_factory=dict)
    frame: int = 0
    world_unit: str = "mm"
    anchor_origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    anchor_axes: np.ndarray = field(default_factory=lambda: np.eye(3))
    plants: tuple = ()

    def __post_init__(self):
        light = np.asarray(self.light, np.float64).reshape(3)
        object.__setattr__(self, "light", light / np.linalg.norm(light))
        object.__setattr__(self, "primitives", tuple(self.primitives))
        ids = [p.leaf_id for p in self.primitives if isinstance(p, Leaf)]
        if len(ids) != len(set(ids)):
            raise CanopyStereoError(f"scene {self.name!r} has duplicate leaf ids")

    # ------------------------------------------------------------------ access
    @property
    def leaves(self) -> list[Leaf]:
        """The leaves in the current frame's pose."""
        return [p for p in self.posed if isinstance(p, Leaf)]

    def leaf(self, leaf_id: int) -> Leaf:
        """The leaf with ``leaf_id`` (current pose); raises :class:`CanopyStereoError`."""
        for lf in self.leaves:
            if lf.leaf_id == leaf_id:
                return lf
        raise CanopyStereoError(f"scene {self.name!r} has no leaf {leaf_id}")

    @property
    def marked_leaf_ids(self) -> list[int]:
        return [lf.leaf_id for lf in self.leaves if lf.marked]

    @property
    def background_distance(self) -> float:
        """Distance of the background plane from the anchor origin along the
        anchor z axis (world units)."""
        n = self.background.normal
        z = self.anchor_axes[2]
        return float(n @ (self.background.centre - self.anchor_origin) / (n @ z))

    # ------------------------------------------------------------------ motion
    @cached_property
    def posed(self) -> tuple:
        """Primitives at :attr:`frame` (leaves turned by their breeze)."""
        if self.frame == 0 or not self.breeze:
            return self.primitives
        out = []
        for p in self.primitives:
            b = self.breeze.get(p.leaf_id) if isinstance(p, Leaf) else None
            if b is not None:
                p = p.rotated_about_base(axis_angle_matrix(b.axis, b.angle(self.frame)))
            out.append(p)
        return tuple(out)

    def at_frame(self, frame: int) -> Scene:
        """The same scene at another frame."""
        if frame < 0:
            raise CanopyStereoError(f"frame must be >= 0, got {frame}")
        return replace(self, frame=int(frame))

    @cached_property
    def packed(self) -> PackedScene:
        """Kernel arrays of the posed primitives."""
        return PackedScene.from_primitives(self.posed)

    # ------------------------------------------------------------------ editing
    def transformed(self, Q, t, s: float, *, world_unit: str | None = None) -> Scene:
        """The scene moved by ``p -> t + s Q p`` (``Q`` a rotation, ``s`` > 0)."""
        Q = np.asarray(Q, np.float64)
        t = np.asarray(t, np.float64)
        prims = tuple(p.transformed(Q, t, s) for p in self.primitives)
        bg_index = next(i for i, p in enumerate(self.primitives) if p is self.background)
        breeze = {k: replace(b, axis=Q @ b.axis) for k, b in self.breeze.items()}
        return replace(self, primitives=prims, background=prims[bg_index], light=Q @ self.light,
                       breeze=breeze, plants=tuple(p.transformed(Q, t, s) for p in self.plants),
                       world_unit=world_unit or self.world_unit,
                       anchor_origin=t + s * Q @ self.anchor_origin,
                       anchor_axes=self.anchor_axes @ Q.T)

    def only_leaves(self, leaf_ids) -> Scene:
        """A copy keeping only the listed leaves (and the background): to see a
        leaf unoccluded."""
        keep = set(int(i) for i in leaf_ids)
        prims = tuple(p for p in self.primitives
                      if p is self.background or (isinstance(p, Leaf) and p.leaf_id in keep))
        return replace(self, primitives=prims, plants=())

    def plant_of_primitive(self) -> np.ndarray:
        """(P,) int32 plant number (1.., :attr:`plants` order) of each primitive, 0 = none."""
        out = np.zeros(len(self.primitives), np.int32)
        for k, plant in enumerate(self.plants, start=1):
            ids = set(plant.leaf_ids)
            for i, p in enumerate(self.primitives):
                if (isinstance(p, Leaf) and p.leaf_id in ids) or i in plant.part_indices:
                    out[i] = k
        return out

    def plants_truth(self) -> list[dict]:
        """Per plant: ``index`` (1.., left to right), ``name``, ``leaf_ids``,
        ``reference`` (``pot_rim``/``soil``), ``reference_point``, ``up``, ``top`` and
        ``height`` (top above the reference surface along ``up``, world units) at this frame."""
        posed = self.posed
        out = []
        for k, plant in enumerate(self.plants, start=1):
            up = np.asarray(plant.up, np.float64)
            top = plant.top(posed)
            out.append({"index": k, "name": plant.name, "leaf_ids": [int(i) for i in plant.leaf_ids],
                        "reference": plant.reference,
                        "reference_point": [float(v) for v in plant.reference_point],
                        "up": [float(v) for v in up], "top": top,
                        "height": top - float(np.asarray(plant.reference_point) @ up)})
        return out

    # ------------------------------------------------------------------ truth
    def truth(self) -> dict:
        """JSON-ready ground truth: scene, seed, frame, unit, background, light, leaves."""
        bg = self.background
        return {
            "scene": self.name, "seed": int(self.seed), "frame": int(self.frame),
            "world_unit": self.world_unit,
            "background": {"point": bg.centre.tolist(), "normal": bg.normal.tolist(),
                           "distance": self.background_distance},
            "anchor": {"origin": self.anchor_origin.tolist(), "axes": self.anchor_axes.tolist()},
            "light": {"direction": self.light.tolist(), "ambient": self.ambient,
                      "diffuse": self.diffuse},
            "marked_leaf_ids": self.marked_leaf_ids,
            "leaves": [lf.truth() for lf in self.leaves],
            "plants": self.plants_truth(),
        }


def rig_anchor(rig) -> tuple[np.ndarray, np.ndarray]:
    """The rig anchor frame ``(origin (3,), axes (3, 3) rows)`` in world coordinates.

    Origin: midpoint of the two camera centres. z: the mean of the two optical
    axes; x: the mean of the cameras' x axes (image right) made orthogonal to
    z; y = z x x (image down). For the paper's rig this is the world frame
    turned by about 4 degrees and moved to (42.8, -64.1, -18.5) mm.
    """
    cams = [decompose_projection(rig.P_left), decompose_projection(rig.P_right)]
    origin = 0.5 * (cams[0].C + cams[1].C)
    z = cams[0].R[2] + cams[1].R[2]
    z /= np.linalg.norm(z)
    x = cams[0].R[0] + cams[1].R[0]
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    return origin, np.vstack([x, np.cross(z, x), z])


def place_in_front_of(scene: Scene, rig) -> Scene:
    """Place a scene built in millimetres in the anchor frame into ``rig``'s world
    frame and unit."""
    origin, axes = rig_anchor(rig)
    s = 0.001 / rig.metres_per_unit
    return scene.transformed(axes.T, origin, s, world_unit=rig.world_unit)
