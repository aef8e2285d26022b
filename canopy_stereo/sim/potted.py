"""Potted plants on a table among objects that are not plants: scenes that test a plant mask.

Each builder takes a seed and returns a :class:`~canopy_stereo.sim.scene.Scene`
in millimetres in the rig anchor frame (x right, y down, z away from the
cameras), with a table top (the ground plane, y = :data:`TABLE_Y`) and a
backdrop 1100 mm away, and with per-plant truth (:class:`~canopy_stereo.sim.scene.PlantSpec`:
leaves, stems, the pot rim as reference surface, up = -y).

* ``potted_distractors``: a green plant in a terracotta pot among things a
  "green things" mask takes for plant: a green watering can (body, lid, spout,
  rose, handle) at the right, a green box in front at the left, and behind it a
  second pot with soil and a green plastic stake.
* ``pots_side_by_side``: two plants that are not green (purple, silver,
  yellowing or variegated; the seed picks) in two pots side by side (terracotta
  and dark green plastic), one measurement set each.

Materials: ``plastic`` (a flat colour with a faint mottle) for the can, the box,
the stake and the plastic pot; ``tinted_leaf`` for leaves of any colour.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.sim.primitives import (
    LABEL_OBJECT,
    LABEL_STEM,
    Cylinder,
    Disc,
    Frustum,
    Leaf,
    Material,
    Rectangle,
    Sphere,
)
from canopy_stereo.sim.scene import Breeze, PlantSpec, Scene

#: Height (anchor y, mm, y down) of the table top the pots and objects stand on.
TABLE_Y = 210.0
#: Distance (mm) of the backdrop.
BACKDROP_Z = 1100.0
#: Linear RGB albedo and vein lightness of the leaf colours (``tinted_leaf``), and variegation.
LEAF_COLOURS = {
    "green": (0.05, 0.17, 0.035, 0.0, 0.4),
    "purple": (0.11, 0.025, 0.09, 0.0, 0.5),
    "silver": (0.34, 0.40, 0.38, 0.0, 0.8),
    "yellowing": (0.45, 0.37, 0.05, 0.0, 0.4),
    "variegated": (0.05, 0.18, 0.04, 1.0, 0.4),
}
_FACING = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
_UP = np.array([0.0, -1.0, 0.0])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _seed(rng) -> int:
    return int(rng.integers(0, 2 ** 31 - 1))


def _plastic(rng, rgb, mottle: float = 0.08) -> Material:
    return Material("plastic", _seed(rng), (*rgb, mottle, 3.0))


def _room(rng) -> list:
    """Backdrop (first: the scene's background) and table top."""
    backdrop = Rectangle([0.0, 0.0, BACKDROP_Z], _FACING, np.inf, np.inf,
                         Material("backdrop", _seed(rng), (3.0,)))
    table_axes = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    table = Rectangle([0.0, TABLE_Y, 700.0], table_axes, np.inf, np.inf,
                      _plastic(rng, (0.30, 0.29, 0.27), 0.35))
    return [backdrop, table]


def _pot(rng, x: float, z: float, height: float, r_base: float, r_top: float, material) -> list:
    """A pot wall standing on the table and its soil 8 mm below the rim."""
    rim_y = TABLE_Y - height
    return [Frustum([x, TABLE_Y, z], _UP, height, r_base, r_top, material),
            Disc([x, rim_y + 8.0, z], _UP, r_top - 1.5, Material("soil", _seed(rng), (1.0,)))]


def _potted_plant(rng, prims: list, leaves: list, breeze: dict, first_id: int, x: float, z: float,
                  rim_y: float, colour: str, height: float, name: str) -> PlantSpec:
    """A stem rising ``height`` mm from the soil with 8-12 leaves on short petioles."""
    r, g, b, variegation, vein = LEAF_COLOURS[colour]
    stem_mat = Material("stem", _seed(rng), (0.7,))
    soil_y = rim_y + 8.0
    top_y = rim_y - height
    lean = rng.uniform(-10, 10, 2)
    pts = [np.array([x, soil_y, z]), np.array([x + lean[0] * 0.5, 0.5 * (soil_y + top_y), z + lean[1] * 0.5]),
           np.array([x + lean[0], top_y + 25.0, z + lean[1]])]
    parts = []
    for i in range(2):
        parts.append(len(prims))
        prims.append(Cylinder(pts[i], pts[i + 1], 4.5 - 1.0 * i, stem_mat))
    parts.append(len(prims))
    prims.append(Sphere(pts[1], 4.5, stem_mat, label=LABEL_STEM))
    leaf_ids = []
    n = int(rng.integers(8, 13))
    for k in range(n):
        frac = 0.25 + 0.75 * k / (n - 1)
        attach = pts[0] + frac * (pts[2] - pts[0])
        az = rng.uniform(0, 2 * np.pi) if k < n - 1 else rng.uniform(-0.3, 0.3) - np.pi / 2
        elev = np.deg2rad(rng.uniform(15, 45) if k < n - 1 else 70.0)
        horiz = np.array([np.cos(az), 0.0, np.sin(az)])
        midrib = np.cos(elev) * horiz + np.sin(elev) * _UP
        base = attach + rng.uniform(8, 16) * _unit(horiz + 0.3 * _UP)
        parts.append(len(prims))
        prims.append(Cylinder(attach, base, 1.6, stem_mat))
        length = rng.uniform(55, 90) * (0.8 if frac > 0.9 else 1.0)
        mat = Material("tinted_leaf", _seed(rng), (r, g, b, rng.uniform(6, 9), variegation, vein))
        normal_hint = _UP * 0.8 + np.array([0, 0, -1.0]) * rng.uniform(0.3, 0.9) + rng.uniform(-0.3, 0.3, 3)
        if abs(_unit(normal_hint) @ midrib) > 0.95:
            normal_hint = np.array([0.0, 0.0, -1.0])
        leaf_id = first_id + k
        lf = Leaf.with_dimensions(leaf_id, base, midrib, normal_hint, length, length * rng.uniform(0.4, 0.55),
                                  mat, droop=-rng.uniform(0.0, 0.004), rise=rng.uniform(0.0, 0.15),
                                  cup=rng.uniform(0.0, 0.006), base_exponent=rng.uniform(0.55, 0.75),
                                  tip_exponent=rng.uniform(0.65, 0.9))
        leaves.append(lf)
        leaf_ids.append(leaf_id)
        breeze[leaf_id] = Breeze(axis=_unit(np.cross(midrib, _UP) + 1e-3), amplitude=np.deg2rad(2.0),
                                 phase=rng.uniform(0, 2 * np.pi), period=rng.uniform(30, 60))
    return PlantSpec(name=name, leaf_ids=tuple(leaf_ids), part_indices=tuple(parts),
                     reference_point=np.array([x, rim_y, z]), up=_UP.copy(), reference="pot_rim")


def _watering_can(rng, x: float, z: float, rgb) -> list:
    """Body (a 150 mm tall tube with a lid), spout with a rose and a handle, standing on the table."""
    mat = _plastic(rng, rgb)
    top = TABLE_Y - 150.0
    prims = [Cylinder([x, TABLE_Y, z], [x, top, z], 62.0, mat, label=LABEL_OBJECT),
             Disc([x, top, z], _UP, 62.0, mat, label=LABEL_OBJECT)]
    spout_end = np.array([x + 175.0, top - 70.0, z - 10.0])
    prims.append(Cylinder([x + 50.0, TABLE_Y - 40.0, z], spout_end, 9.0, mat, label=LABEL_OBJECT))
    prims.append(Sphere(spout_end, 15.0, mat, label=LABEL_OBJECT))
    handle = [np.array([x - 30.0, top, z]), np.array([x - 45.0, top - 55.0, z]),
              np.array([x - 85.0, top - 40.0, z]), np.array([x - 66.0, top + 50.0, z])]
    for a, b in zip(handle[:-1], handle[1:]):
        prims.append(Cylinder(a, b, 8.0, mat, label=LABEL_OBJECT))
    for p in handle[1:-1]:
        prims.append(Sphere(p, 8.0, mat, label=LABEL_OBJECT))
    return prims


def _box(rng, x: float, z: float, w: float, h: float, d: float, rgb) -> list:
    """A closed box on the table: front, top and side faces."""
    mat = _plastic(rng, rgb, 0.12)
    cy = TABLE_Y - h / 2
    top_axes = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    side_axes = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]])
    return [Rectangle([x, cy, z - d / 2], _FACING, w / 2, h / 2, mat, label=LABEL_OBJECT),
            Rectangle([x, TABLE_Y - h, z], top_axes, w / 2, d / 2, mat, label=LABEL_OBJECT),
            Rectangle([x - w / 2, cy, z], side_axes, d / 2, h / 2, mat, label=LABEL_OBJECT),
            Rectangle([x + w / 2, cy, z], -side_axes, d / 2, h / 2, mat, label=LABEL_OBJECT)]


def build_potted_distractors(seed: int = 0) -> Scene:
    """A green potted plant among a green watering can, a pot with soil and a stake, a green box."""
    rng = np.random.default_rng([seed, 404])
    prims = _room(rng)
    background = prims[0]
    leaves, breeze = [], {}
    px, pz = -20.0 + rng.uniform(-15, 15), 760.0 + rng.uniform(-20, 20)
    prims += _pot(rng, px, pz, 115.0, 62.0, 82.0, Material("pot", _seed(rng), (115.0,)))
    plant = _potted_plant(rng, prims, leaves, breeze, 1, px, pz, TABLE_Y - 115.0, "green",
                          rng.uniform(230, 270), "plant")
    # a second pot with soil and a green stake, behind at the left
    sx, sz = -190.0 + rng.uniform(-10, 10), 950.0
    prims += _pot(rng, sx, sz, 90.0, 50.0, 64.0, _plastic(rng, (0.04, 0.09, 0.04), 0.1))
    stake_mat = _plastic(rng, (0.05, 0.20, 0.04), 0.05)
    prims.append(Cylinder([sx - 20.0, TABLE_Y - 82.0, sz], [sx - 24.0, TABLE_Y - 330.0, sz - 5.0], 4.0,
                          stake_mat, label=LABEL_OBJECT))
    # a green box in front at the left, a green watering can at the right
    prims += _box(rng, -260.0, 620.0, 100.0, 90.0, 90.0, (0.06, 0.22, 0.05))
    prims += _watering_can(rng, 190.0 + rng.uniform(-10, 10), 640.0, (0.10, 0.33, 0.12))
    return Scene(name="potted_distractors", seed=seed, primitives=prims + leaves, background=background,
                 light=[-0.3, -0.8, -0.5], breeze=breeze, plants=(plant,))


def build_pots_side_by_side(seed: int = 0) -> Scene:
    """Two plants that are not green, in two pots side by side."""
    rng = np.random.default_rng([seed, 505])
    prims = _room(rng)
    background = prims[0]
    leaves, breeze = [], {}
    pairs = [("purple", "silver"), ("yellowing", "variegated"), ("silver", "purple")]
    colours = pairs[seed % len(pairs)]
    specs = []
    first = 1
    for k, (x, colour) in enumerate(zip((-150.0 + rng.uniform(-10, 10), 150.0 + rng.uniform(-10, 10)), colours)):
        z = 740.0 + rng.uniform(-30, 30)
        material = (Material("pot", _seed(rng), (110.0,)) if k == 0 else
                    _plastic(rng, (0.03, 0.08, 0.035), 0.1))
        prims += _pot(rng, x, z, 110.0, 60.0, 80.0, material)
        specs.append(_potted_plant(rng, prims, leaves, breeze, first, x, z, TABLE_Y - 110.0, colour,
                                   rng.uniform(200, 260), f"{colour} plant"))
        first += 20
    return Scene(name="pots_side_by_side", seed=seed, primitives=prims + leaves, background=background,
                 light=[-0.3, -0.8, -0.5], breeze=breeze, plants=tuple(specs))
