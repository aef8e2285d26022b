"""Synthetic plant scenes seen through a real stereo rig, with exact ground truth.

The simulator ray-casts analytic scenes (curved leaf blades with leaf-shaped
outlines, cylindrical stems, a pot with soil, a background plane at a known
distance) through the rig's own 3x4 ``P`` matrices, with the pipeline's lens
distortion model when the rig has one, supersampled anti-aliasing and a
simple sensor model (exposure/gain mismatch, vignetting, noise). Textures
(veins, variegation, colour noise) are functions of the surface point, so the
two views agree photometrically, and every pixel knows the world point it sees.

Python API (world frame and unit of the rig throughout)::

    from canopy_stereo.sim import render_scene
    sim = render_scene("croton", rig=None, seed=0, frame=0)   # rig None: config/paper_rig.yaml
    sim.left, sim.right            # (H, W, 3) uint8 BGR images
    sim.xyz_left, sim.xyz_right    # (H, W, 3) float64 world point at each pixel centre, NaN = none
    sim.leaf_ids_left              # (H, W) uint16 leaf id at each pixel centre, 0 = no leaf
    sim.labels_left                # (H, W) uint8 class (LABEL_NAMES: leaf, stem, pot, soil, ...)
    sim.truth                      # JSON-ready dict, see below
    sim.scene, sim.rig             # the placed Scene and the Rig

``truth`` holds ``scene``, ``seed``, ``frame``, ``world_unit``, ``image_size``,
``background`` (``point``, ``normal``, ``distance`` from the point between
the cameras), ``marked_leaf_ids`` and ``leaves``: per leaf ``id``, ``name``,
``marked``, ``length`` (midrib arc length, base to tip), ``width`` (arc length
across the widest section), ``length_chord``/``width_chord`` (straight
distances), ``area`` (one-sided, curved), ``pose`` (``base``, ``tip``,
``width_endpoints``, ``axes``), ``shape`` and ``pixels_left``/``pixels_right``
(pixels where the leaf is visible).

Scenes (:data:`SCENES`): ``croton`` (the paper's two marked leaves of
97 x 160 and 86 x 145 mm plus other leaves, 550-800 mm away), ``citrus_branch``
(many 30-80 mm leaves with occlusions), ``seedling_tray`` (top view). A seed
varies the layout; ``frame`` > 0 sways the leaves in a gentle breeze about
their bases (frame 0 is the rest pose), with the truth of that frame.

Lower level: :func:`~canopy_stereo.sim.scenes.build_scene` (scene in mm in
the rig anchor frame), :func:`~canopy_stereo.sim.scene.place_in_front_of`,
:func:`~canopy_stereo.sim.render.render_pair` (any Scene, any Rig,
:class:`CameraEffects`, ``supersample``) and
:func:`~canopy_stereo.sim.render.visible_from` (occlusion test of world points).
"""
from canopy_stereo.sim.primitives import (
    LABEL_NAMES,
    Cylinder,
    Disc,
    Frustum,
    Leaf,
    Material,
    Rectangle,
    Sphere,
)
from canopy_stereo.sim.render import SimResult, first_hits, render_pair, render_view, visible_from
from canopy_stereo.sim.scene import Breeze, Scene, place_in_front_of, rig_anchor
from canopy_stereo.sim.scenes import CROTON_MARKED, SCENES, build_scene
from canopy_stereo.sim.sensor import CLEAN, CameraEffects, sample_pattern
from canopy_stereo.sim.simulate import (
    default_rig_path,
    render_scene,
    resolve_rig,
    rig_at_resolution,
    scene_for_rig,
)

__all__ = [
    "Breeze", "CLEAN", "CROTON_MARKED", "CameraEffects", "Cylinder", "Disc", "Frustum",
    "LABEL_NAMES", "Leaf", "Material", "Rectangle", "SCENES", "Scene", "SimResult", "Sphere",
    "build_scene", "default_rig_path", "first_hits", "place_in_front_of", "render_pair",
    "render_scene", "render_view", "resolve_rig", "rig_anchor", "rig_at_resolution",
    "sample_pattern", "scene_for_rig",
    "visible_from",
]
