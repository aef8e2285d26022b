"""Named scenes: ``croton``, ``citrus_branch``, ``seedling_tray``, ``potted_distractors``,
``pots_side_by_side`` (the last two in :mod:`canopy_stereo.sim.potted`).

Each builder takes a seed and returns a :class:`~canopy_stereo.sim.scene.Scene`
in millimetres in the rig anchor frame (x right, y down, z away from the
cameras, origin between them; see :func:`~canopy_stereo.sim.scene.rig_anchor`).
Seed 0 is the reference layout; other seeds move, turn, resize and recolour
the plants (the croton's two marked leaves keep their exact sizes).

* ``croton``: a potted croton seen from the side about 550-800 mm away, as in
  the paper's laboratory test: two marked, unoccluded leaves of 97 x 160 mm
  (leaf 1) and 86 x 145 mm (leaf 2), up to 13 other variegated leaves placed
  so that they never hide the marked ones (checked by ray casting), a stem, a
  terracotta pot with soil and a textured backdrop 1000 mm away.
* ``citrus_branch``: a branch of a citrus tree about 450-600 mm away with
  many 30-80 mm leaves occluding each other, twigs and one or two fruits, in
  front of blotchy foliage (with patches of sky) 1500 mm away.
* ``seedling_tray``: a tray of seedlings seen from above: the tray's soil
  surface 420 mm away (the background) with cells, and small plants of two
  cotyledons and up to two true leaves rising 10-35 mm towards the cameras;
  each seedling is a plant of the per-plant truth (reference: the soil, up:
  towards the cameras).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.sim.potted import build_pots_side_by_side, build_potted_distractors
from canopy_stereo.sim.primitives import (
    LABEL_STEM,
    Cylinder,
    Disc,
    Frustum,
    Leaf,
    Material,
    Rectangle,
    Sphere,
)
from canopy_stereo.sim.raycast import PackedScene, trace_rays
from canopy_stereo.sim.scene import Breeze, PlantSpec, Scene

#: Marked croton leaves of the paper (width, length) in mm.
CROTON_MARKED = {1: (97.0, 160.0), 2: (86.0, 145.0)}

#: Backdrop plane facing the cameras (axes rows: x right, y up, normal towards the cameras).
_FACING_AXES = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


def _seed(rng) -> int:
    return int(rng.integers(0, 2 ** 31 - 1))


def _stem_chain(points, radii, material, label=LABEL_STEM) -> list:
    """Cylinders along a polyline with spheres at the joints (no gaps at bends)."""
    prims = []
    for i in range(len(points) - 1):
        prims.append(Cylinder(points[i], points[i + 1], radii[i], material, label=label))
        if i > 0:
            prims.append(Sphere(points[i], max(radii[i - 1], radii[i]), material, label=label))
    return prims


def _point_on_chain(points, y):
    """Point of a (roughly vertical) polyline at height ``y`` (linear in y)."""
    for a, b in zip(points[:-1], points[1:]):
        lo, hi = sorted((a[1], b[1]))
        if lo <= y <= hi:
            t = (y - a[1]) / (b[1] - a[1])
            return a + t * (b - a)
    raise CanopyStereoError(f"height {y} is not on the stem")


def _breeze(rng, leaf: Leaf, amplitude_deg) -> Breeze:
    """A gentle sway about an axis across the midrib, mixed with a little twist."""
    across, normal, midrib = leaf.axes[1], leaf.axes[2], leaf.axes[0]
    axis = _unit(across + rng.uniform(-0.4, 0.4) * normal + rng.uniform(-0.3, 0.3) * midrib)
    return Breeze(axis=axis, amplitude=np.deg2rad(rng.uniform(*amplitude_deg)),
                  phase=rng.uniform(0, 2 * np.pi), period=rng.uniform(30.0, 60.0))


class _Occlusion:
    """Whether new primitives would hide any part of protected leaves from
    viewpoints along a 120 mm baseline centred on the anchor origin (the paper
    rig's cameras are at about -15 and +15 mm), by exact ray casting."""

    VIEWPOINTS = np.array([[x, 0.0, 0.0] for x in (-60.0, -30.0, -15.0, 0.0, 15.0, 30.0, 60.0)])

    def __init__(self):
        self.points = np.zeros((0, 3))

    def protect(self, leaf: Leaf) -> None:
        self.points = np.vstack([self.points, leaf.surface_points()])

    def hides(self, prims) -> bool:
        if len(self.points) == 0:
            return False
        packed = PackedScene.from_primitives(prims)
        origins = np.repeat(self.VIEWPOINTS, len(self.points), axis=0)
        vec = np.tile(self.points, (len(self.VIEWPOINTS), 1)) - origins
        dist = np.linalg.norm(vec, axis=1)
        t, _ = trace_rays(origins, vec / dist[:, None], packed.kinds, packed.axes,
                          packed.origins, packed.geometry)
        return bool(np.any(t < dist - 1e-6))


# --------------------------------------------------------------------------- croton


def build_croton(seed: int = 0) -> Scene:
    """The paper's potted croton, side view (see the module docstring)."""
    rng = np.random.default_rng([seed, 101])
    x0 = -20.0 + rng.uniform(-15, 15)
    z0 = 685.0 + rng.uniform(-15, 15)
    pot_top = 170.0
    stem_mat = Material("stem", _seed(rng), (0.55,))
    prims = [
        Rectangle([0.0, 0.0, 1000.0], _FACING_AXES, np.inf, np.inf,
                  Material("backdrop", _seed(rng), (3.0,))),
        Frustum([x0, pot_top + 130.0, z0], [0, -1, 0], 130.0, 72.0, 95.0,
                Material("pot", _seed(rng), (130.0,))),
        Disc([x0, pot_top + 8.0, z0], [0, -1, 0], 93.5, Material("soil", _seed(rng), (1.0,))),
    ]
    background = prims[0]
    lean = rng.uniform(-8, 8, size=3)
    stem_pts = [np.array([x0, pot_top + 8.0, z0]), np.array([x0 + lean[0], 60.0, z0 - 3.0]),
                np.array([x0 + lean[1], -80.0, z0 + 4.0]), np.array([x0 + lean[2], -215.0, z0])]
    prims += _stem_chain(stem_pts, [7.5, 6.5, 5.0], stem_mat)

    leaves, breeze = [], {}

    def add_leaf(leaf_id, attach_y, petiole_dir, petiole_len, midrib, normal_hint, length, width,
                 age, droop, rise, cup, exps, marked=False):
        stem_point = _point_on_chain(stem_pts, attach_y)
        base = stem_point + petiole_len * _unit(petiole_dir)
        mat = Material("croton", _seed(rng), (age, rng.uniform(11, 15), rng.uniform(0.9, 1.4),
                                              rng.uniform(0.9, 1.1)))
        lf = Leaf.with_dimensions(leaf_id, base, midrib, normal_hint, length, width, mat,
                                  droop=droop, rise=rise, cup=cup, base_exponent=exps[0],
                                  tip_exponent=exps[1], marked=marked,
                                  name=f"leaf{leaf_id}" if marked else "")
        # the petiole meets the blade from below, so it never pokes through the upper side
        petiole = Cylinder(stem_point, base + 1.0 * lf.axes[0] - 2.8 * lf.axes[2], 2.6, stem_mat)
        return lf, petiole

    # the two marked leaves face the cameras, one on each side of the stem
    jitter = lambda s: rng.uniform(-s, s, size=3)  # noqa: E731
    marked_specs = [
        (1, -95.0, [-0.6, -0.3, -0.75], [-0.85, -0.25, -0.3], [-0.25, -0.35, -1.0]),
        (2, 5.0, [0.6, -0.2, -0.75], [0.85, -0.15, -0.35], [0.3, -0.3, -1.0]),
    ]
    protected = _Occlusion()
    for leaf_id, y, pdir, mdir, nhint in marked_specs:
        width, length = CROTON_MARKED[leaf_id]
        lf, pet = add_leaf(leaf_id, y + rng.uniform(-10, 10), np.add(pdir, jitter(0.05)), 32.0,
                           np.add(mdir, jitter(0.06)), np.add(nhint, jitter(0.08)), length, width,
                           age=rng.uniform(0.3, 0.8), droop=-0.0009, rise=0.10, cup=0.0016,
                           exps=(0.62, 0.85), marked=True)
        leaves.append(lf)
        prims.append(pet)
        protected.protect(lf)
        breeze[leaf_id] = _breeze(rng, lf, (1.0, 2.0))

    next_id = 3
    for slot in _CROTON_SLOTS:
        for _ in range(40):
            lf, pet = _croton_candidate(rng, add_leaf, next_id, slot)
            if not protected.hides([lf, pet]):
                leaves.append(lf)
                prims.append(pet)
                breeze[next_id] = _breeze(rng, lf, (1.5, 3.5))
                next_id += 1
                break
    return Scene(name="croton", seed=seed, primitives=prims + leaves, background=background,
                 light=[-0.35, -0.75, -0.55], breeze=breeze)


#: Other croton leaves: (attach height range (mm, y down), azimuth centre and spread
#: (rad; 0 = right, pi/2 = away from the cameras, -pi/2 = towards them), elevation range
#: (deg), length range (mm), age range). They avoid the marked leaves' image regions.
_CROTON_SLOTS = [
    ((-214.0, -200.0), 0.4, 0.4, (40, 70), (70, 100), (0.0, 0.3)),
    ((-214.0, -200.0), np.pi - 0.4, 0.4, (40, 70), (70, 100), (0.0, 0.3)),
    ((-214.0, -200.0), np.pi / 2, 0.5, (45, 75), (60, 90), (0.0, 0.3)),
    ((-190.0, -120.0), 0.0, 0.6, (-10, 30), (110, 165), (0.2, 1.0)),
    ((-170.0, -90.0), 0.8, 0.3, (-10, 25), (100, 160), (0.2, 1.0)),
    ((40.0, 110.0), np.pi, 0.6, (-25, 20), (110, 170), (0.3, 1.0)),
    ((40.0, 110.0), np.pi + 0.7, 0.3, (-25, 10), (100, 160), (0.3, 1.0)),
    ((80.0, 120.0), 0.0, 0.6, (-30, 10), (100, 160), (0.3, 1.0)),
    ((-30.0, 20.0), np.pi, 0.5, (-30, 0), (100, 150), (0.2, 1.0)),
    ((-150.0, 60.0), np.pi / 2, 0.6, (-10, 30), (100, 140), (0.2, 1.0)),
    ((-150.0, 60.0), np.pi / 2, 0.6, (-10, 30), (100, 140), (0.2, 1.0)),
    ((60.0, 120.0), -np.pi / 2, 0.4, (-30, 0), (90, 130), (0.2, 1.0)),
    ((-60.0, 40.0), np.pi / 2 + 0.6, 0.4, (-20, 20), (100, 150), (0.2, 1.0)),
]


def _croton_candidate(rng, add_leaf, leaf_id, slot):
    """A random croton leaf and its petiole in one of the :data:`_CROTON_SLOTS`."""
    (y0, y1), az0, daz, (e0, e1), (l0, l1), (a0, a1) = slot
    attach_y = rng.uniform(y0, y1)
    az = az0 + rng.uniform(-daz, daz)
    horiz = np.array([np.cos(az), 0.0, np.sin(az)])
    elev = np.deg2rad(rng.uniform(e0, e1))
    midrib = np.cos(elev) * horiz + np.array([0.0, -np.sin(elev), 0.0])
    normal_hint = (np.array([0.0, -0.6, 0.0]) + rng.uniform(0.6, 1.2) * np.array([0, 0, -1.0])
                   + rng.uniform(-0.35, 0.35, 3))
    length = rng.uniform(l0, l1)
    width = length * rng.uniform(0.45, 0.65)
    return add_leaf(leaf_id, attach_y, horiz + [0, -0.4, 0],
                    rng.uniform(10, 20) if attach_y < -195 else rng.uniform(15, 35), midrib,
                    normal_hint, length, width, age=rng.uniform(a0, a1),
                    droop=-rng.uniform(0.0, 0.003), rise=rng.uniform(0.0, 0.25),
                    cup=rng.uniform(0.0, 0.004),
                    exps=(rng.uniform(0.5, 0.8), rng.uniform(0.6, 1.0)))


# --------------------------------------------------------------------------- citrus


def build_citrus_branch(seed: int = 0) -> Scene:
    """A leafy citrus branch with occlusions (see the module docstring)."""
    rng = np.random.default_rng([seed, 202])
    bark = Material("bark", _seed(rng))
    twig_mat = Material("stem", _seed(rng), (0.8,))
    background = Rectangle([0.0, 0.0, 1500.0], _FACING_AXES, np.inf, np.inf,
                           Material("foliage", _seed(rng), (40.0,)))
    prims = [background]
    start = np.array([-330.0, 150.0, 560.0]) + rng.uniform(-20, 20, 3)
    end = np.array([330.0, -150.0, 470.0]) + rng.uniform(-20, 20, 3)
    n_seg = 5
    branch = [start + (end - start) * i / n_seg + (rng.uniform(-15, 15, 3) if 0 < i < n_seg else 0)
              for i in range(n_seg + 1)]
    prims += _stem_chain(branch, np.linspace(8.0, 5.0, n_seg), bark)
    twigs = []
    for _ in range(int(rng.integers(5, 8))):
        t = rng.uniform(0.1, 0.9)
        seg = min(int(t * n_seg), n_seg - 1)
        frac = t * n_seg - seg
        p0 = branch[seg] + frac * (branch[seg + 1] - branch[seg])
        along = _unit(branch[seg + 1] - branch[seg])
        side = _unit(np.cross(along, [0.0, 0.0, 1.0])) * rng.choice([-1.0, 1.0])
        d = _unit(0.5 * along + side + rng.uniform(-0.5, 0.5) * np.array([0, 0, 1.0]))
        p1 = p0 + rng.uniform(90, 170) * d
        prims.append(Cylinder(p0, p1, rng.uniform(2.2, 3.0), twig_mat))
        twigs.append((p0, p1))
    for seg in range(n_seg):
        twigs.append((branch[seg], branch[seg + 1]))

    leaves, breeze = [], {}
    leaf_id = 1
    for p0, p1 in twigs:
        axis = p1 - p0
        L = np.linalg.norm(axis)
        axis = axis / L
        s = rng.uniform(5.0, 15.0)
        side = 1.0
        while s < L - 5.0:
            node = p0 + s * axis
            side = -side
            perp = _unit(np.cross(axis, [0.0, 0.0, 1.0]) * side + rng.uniform(-0.4, 0.4, 3))
            midrib = _unit(np.cos(np.deg2rad(rng.uniform(35, 60))) * axis
                           + np.sin(np.deg2rad(rng.uniform(35, 60))) * perp
                           + rng.uniform(-0.6, 0.4) * np.array([0, 0, 1.0]))
            normal_hint = np.array([0.0, 0.0, -1.0]) + rng.uniform(-0.9, 0.9, 3)
            if abs(_unit(normal_hint) @ midrib) > 0.95:
                normal_hint = np.array([0.0, 0.0, -1.0])
            length = rng.uniform(30.0, 80.0)
            width = length * rng.uniform(0.40, 0.55)
            base = node + rng.uniform(6.0, 10.0) * _unit(midrib + 0.3 * perp)
            mat = Material("citrus", _seed(rng), (rng.uniform(0, 1), rng.uniform(8, 11),
                                                  rng.uniform(0.9, 1.3), rng.uniform(0.85, 1.15)))
            lf = Leaf.with_dimensions(leaf_id, base, midrib, normal_hint, length, width, mat,
                                      droop=-rng.uniform(0.0, 0.006), rise=rng.uniform(0.0, 0.2),
                                      cup=rng.uniform(0.0, 0.01),
                                      base_exponent=rng.uniform(0.55, 0.75),
                                      tip_exponent=rng.uniform(0.65, 0.9))
            prims.append(Cylinder(node, base + 1.0 * _unit(midrib), 1.3, twig_mat))
            leaves.append(lf)
            breeze[leaf_id] = _breeze(rng, lf, (1.5, 4.0))
            leaf_id += 1
            s += rng.uniform(14.0, 24.0)
    for _ in range(int(rng.integers(1, 3))):
        seg = int(rng.integers(1, n_seg - 1))
        drop = np.array([rng.uniform(-30, 30), rng.uniform(45, 60), rng.uniform(-20, 10)])
        hang = branch[seg] + drop
        r = rng.uniform(30.0, 38.0)
        prims.append(Cylinder(branch[seg], hang + np.array([0, -r + 2.0, 0]), 1.8, twig_mat))
        prims.append(Sphere(hang, r, Material("fruit", _seed(rng))))
    return Scene(name="citrus_branch", seed=seed, primitives=prims + leaves, background=background,
                 light=[-0.2, -0.8, -0.55], breeze=breeze)


# --------------------------------------------------------------------------- seedlings


def build_seedling_tray(seed: int = 0) -> Scene:
    """A seedling tray seen from above (see the module docstring)."""
    rng = np.random.default_rng([seed, 303])
    depth = 420.0
    pitch = 50.0
    offset = rng.uniform(-10, 10, 2)
    background = Rectangle([offset[0], offset[1], depth], _FACING_AXES, np.inf, np.inf,
                           Material("tray", _seed(rng), (pitch, 1.6, 0.9)))
    stem_mat = Material("stem", _seed(rng), (0.9,))
    prims = [background]
    leaves, breeze, plants = [], {}, []
    leaf_id = 1
    for i in range(-5, 5):
        for j in range(-4, 4):
            # cell centres in the tray's own (x right, y up) coordinates, then anchor frame
            cx = offset[0] + (i + 0.5) * pitch
            cy = offset[1] - (j + 0.5) * pitch
            if rng.uniform() < 0.2:
                continue
            foot = np.array([cx + rng.uniform(-6, 6), cy + rng.uniform(-6, 6), depth])
            height = rng.uniform(10.0, 35.0)
            top = foot + height * _unit([rng.uniform(-0.25, 0.25), rng.uniform(-0.25, 0.25), -1.0])
            prims.append(Cylinder(foot, top, rng.uniform(1.0, 1.5), stem_mat))
            stem_index, first_leaf = len(prims) - 1, leaf_id
            age = rng.uniform(0, 1)
            theta = rng.uniform(0, 2 * np.pi)
            specs = [(theta, rng.uniform(10, 16), rng.uniform(0.55, 0.7), (0.5, 0.5)),
                     (theta + np.pi + rng.uniform(-0.2, 0.2), rng.uniform(10, 16),
                      rng.uniform(0.55, 0.7), (0.5, 0.5))]
            for _ in range(int(rng.integers(0, 3))):
                specs.append((theta + rng.choice([-1, 1]) * np.pi / 2 + rng.uniform(-0.4, 0.4),
                              rng.uniform(14, 26), rng.uniform(0.45, 0.6), (0.6, 0.8)))
            for ang, length, ratio, exps in specs:
                elev = np.deg2rad(rng.uniform(10, 35))
                midrib = np.array([np.cos(ang) * np.cos(elev), np.sin(ang) * np.cos(elev),
                                   -np.sin(elev)])
                base = top + 1.0 * midrib
                params = (age, rng.uniform(5, 8), rng.uniform(0.8, 1.2), rng.uniform(0.9, 1.1))
                mat = Material("seedling", _seed(rng), params)
                lf = Leaf.with_dimensions(leaf_id, base, midrib, [0.0, 0.0, -1.0], length,
                                          length * ratio, mat, droop=-rng.uniform(0.0, 0.01),
                                          rise=rng.uniform(0.0, 0.1), cup=rng.uniform(0.0, 0.02),
                                          base_exponent=exps[0], tip_exponent=exps[1])
                leaves.append(lf)
                breeze[leaf_id] = _breeze(rng, lf, (1.0, 3.0))
                leaf_id += 1
            plants.append(PlantSpec(name=f"seedling {len(plants) + 1}",
                                    leaf_ids=tuple(range(first_leaf, leaf_id)), part_indices=(stem_index,),
                                    reference_point=foot.copy(), up=np.array([0.0, 0.0, -1.0]),
                                    reference="soil"))
    return Scene(name="seedling_tray", seed=seed, primitives=prims + leaves, background=background,
                 light=[-0.3, -0.4, -0.85], breeze=breeze, plants=tuple(plants))


#: Scene name -> builder(seed) -> Scene (millimetres, rig anchor frame).
SCENES = {
    "croton": build_croton,
    "citrus_branch": build_citrus_branch,
    "seedling_tray": build_seedling_tray,
    "potted_distractors": build_potted_distractors,
    "pots_side_by_side": build_pots_side_by_side,
}


def build_scene(name: str, seed: int = 0) -> Scene:
    """The named scene (rest pose, millimetres, rig anchor frame)."""
    try:
        builder = SCENES[name]
    except KeyError:
        raise CanopyStereoError(
            f"unknown scene {name!r}; choose one of {', '.join(SCENES)}") from None
    if int(seed) < 0:
        raise CanopyStereoError(f"seed must be >= 0, got {seed}")
    return builder(int(seed))
