"""Render a scene through a stereo rig: images plus exact per-pixel ground truth."""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import camera_centre, validate_projection
from canopy_stereo.io.rig import unit_to_metres
from canopy_stereo.sim.raycast import (
    bin_primitives,
    projected_boxes,
    tile_boxes,
    trace_image,
    trace_rays,
)
from canopy_stereo.sim.scene import Scene
from canopy_stereo.sim.sensor import (
    CameraEffects,
    check_distortion,
    ideal_sample_map,
    sample_pattern,
)

#: Side of the square pixel tiles used for culling.
TILE_SIZE = 16


@dataclass
class ViewRender:
    """One camera's render before sensor effects.

    Attributes:
        radiance: (H, W, 3) float32 linear RGB (anti-aliased).
        xyz: (H, W, 3) float64 world point seen at each pixel centre, NaN where nothing.
        prim_index: (H, W) int32 index into the scene's posed primitives (-1 none).
    """

    radiance: np.ndarray
    xyz: np.ndarray
    prim_index: np.ndarray


def _trace(scene: Scene, P, Dl, size, offsets, weights, tile_size: int, model=None) -> ViewRender:
    """Trace the sample pattern ``offsets``/``weights`` at every pixel of a
    ``size = (w, h)`` grid (see :func:`~canopy_stereo.sim.raycast.trace_image`)."""
    w, h = size
    ideal = None if Dl is None else ideal_sample_map(P, Dl, (w, h), offsets, model=model)
    M = P[:, :3]
    Minv = np.linalg.inv(M) * np.sign(np.linalg.det(M))
    C = camera_centre(P)
    packed = scene.packed
    boxes = projected_boxes(P, packed.corners)
    tiles = tile_boxes(ideal, offsets, w, h, tile_size)
    near = packed.near_distances(C)
    start, prims = bin_primitives(tiles, boxes, near=near)
    radiance = np.empty((h, w, 3), np.float32)
    xyz = np.empty((h, w, 3), np.float64)
    prim_index = np.empty((h, w), np.int32)
    dummy = np.zeros((1, 1, 1, 2))
    trace_image(h, w, tile_size, offsets, weights, dummy if ideal is None else ideal,
                ideal is not None, Minv, C, start, prims, near, packed.kinds, packed.axes,
                packed.local_origins(C), packed.geometry, packed.materials,
                scene.light, float(scene.ambient), float(scene.diffuse),
                1000.0 * unit_to_metres(scene.world_unit), radiance, xyz, prim_index)
    return ViewRender(radiance=radiance, xyz=xyz, prim_index=prim_index)


def render_view(scene: Scene, P, D, image_size, *, supersample: int = 2,
                tile_size: int = TILE_SIZE, samples=None, model: str | None = None) -> ViewRender:
    """Ray-cast one view of ``scene`` through the camera ``P`` (3, 4) with
    distortion ``D`` of ``model`` (None or all zero = none; ``model`` as
    :mod:`canopy_stereo.geometry.distortion`, None = OpenCV's up to 12 terms).

    The world point of a pixel is the hit of the exact ray through its centre:
    with no distortion it projects through ``P`` onto the pixel centre; with
    distortion, ``distort_pixels(P, D, project(P, X))`` is the pixel centre.
    ``supersample`` 2 (quincunx) traces the pixel centres and, once, the grid of
    pixel corners that neighbouring pixels share: 5 samples per pixel for 2 rays.
    ``samples``: an explicit ``(offsets (S, 2), weights (S,))`` pattern instead
    (sample 0 the pixel centre), e.g. :func:`~canopy_stereo.sim.sensor.lattice_pattern`.
    """
    P = validate_projection(P)
    w, h = (int(v) for v in image_size)
    Dl = check_distortion(D, "D", model=model)
    if samples is not None:
        offsets, weights = (np.asarray(a, np.float64) for a in samples)
        if offsets.ndim != 2 or offsets.shape[1] != 2 or weights.shape != (len(offsets),) \
                or np.any(offsets[0] != 0):
            raise CanopyStereoError("samples must be (offsets (S, 2) with offsets[0] = (0, 0), weights (S,))")
        return _trace(scene, P, Dl, (w, h), offsets, weights, tile_size, model)
    offsets, weights = sample_pattern(supersample)
    if supersample != 2:
        return _trace(scene, P, Dl, (w, h), offsets, weights, tile_size, model)
    centre = _trace(scene, P, Dl, (w, h), offsets[:1], np.ones(1), tile_size, model)
    corners = _trace(scene, P, Dl, (w + 1, h + 1), offsets[1:2], np.ones(1), tile_size, model).radiance
    quad = corners[:-1, :-1] + corners[:-1, 1:] + corners[1:, :-1] + corners[1:, 1:]
    radiance = weights[0] * centre.radiance + weights[1] * quad
    return ViewRender(radiance=radiance.astype(np.float32), xyz=centre.xyz,
                      prim_index=centre.prim_index)


@dataclass
class SimResult:
    """A rendered stereo pair with its ground truth (all in the rig's world frame and unit).

    Attributes:
        scene: the :class:`~canopy_stereo.sim.scene.Scene` (at :attr:`frame`).
        rig: the :class:`~canopy_stereo.io.rig.Rig` it was seen through.
        left, right: (H, W, 3) uint8 BGR images.
        xyz_left, xyz_right: (H, W, 3) float64 world point seen at each pixel centre, NaN
            where the ray hits nothing.
        leaf_ids_left, leaf_ids_right: (H, W) uint16 leaf id at each pixel centre, 0 = no leaf.
        labels_left, labels_right: (H, W) uint8 pixel class
            (:data:`~canopy_stereo.sim.primitives.LABEL_NAMES`).
        truth: JSON-ready dict: scene, seed, frame, world_unit, background, leaves (id,
            name, marked, length, width, chords, area, pose, visible pixels per view),
            plants (per plant: index, reference surface, top, height; see
            :meth:`~canopy_stereo.sim.scene.Scene.plants_truth`), ...
        timings: seconds per stage: ``left``, ``right`` (ray casting of each view,
            run on two threads) and ``sensor`` (sensor model and truth).
        plants_left, plants_right: (H, W) uint16 plant number (``truth["plants"]`` index)
            at each pixel centre, 0 = no plant (all 0 for scenes without plants).
    """

    scene: Scene
    rig: object
    left: np.ndarray
    right: np.ndarray
    xyz_left: np.ndarray
    xyz_right: np.ndarray
    leaf_ids_left: np.ndarray
    leaf_ids_right: np.ndarray
    labels_left: np.ndarray
    labels_right: np.ndarray
    truth: dict
    timings: dict = field(default_factory=dict)
    plants_left: np.ndarray | None = None
    plants_right: np.ndarray | None = None

    @property
    def seed(self) -> int:
        return self.scene.seed

    @property
    def frame(self) -> int:
        return self.scene.frame

    def leaf_mask(self, side: str = "left") -> np.ndarray:
        """(H, W) bool: pixels whose centre sees a leaf."""
        ids = self.leaf_ids_left if side == "left" else self.leaf_ids_right
        return ids > 0


def render_pair(scene: Scene, rig, *, supersample: int = 2, effects: CameraEffects | None = None,
                tile_size: int = TILE_SIZE, right_scene: Scene | None = None) -> SimResult:
    """Render ``scene`` (already placed in ``rig``'s world frame) through both cameras.

    Args:
        scene: the scene, in the rig's world frame and unit.
        rig: :class:`~canopy_stereo.io.rig.Rig`.
        supersample: anti-aliasing (see :func:`~canopy_stereo.sim.sensor.sample_pattern`).
        effects: sensor response (default :class:`CameraEffects`()); the noise is
            drawn from ``(scene.seed, scene.frame)`` so output is deterministic.
        right_scene: what the right camera sees, when not ``scene``: the same scene at the
            right camera's own capture instant (:mod:`canopy_stereo.sim.sequence`). The
            truth dict is the left scene's (its leaves' ``pixels_right`` count the right view).
    """
    scenes = {"left": scene, "right": scene if right_scene is None else right_scene}
    for sc in scenes.values():
        if sc.world_unit != rig.world_unit:
            raise CanopyStereoError(f"scene is in {sc.world_unit} but the rig in {rig.world_unit}: "
                                    "place the scene in front of the rig first")
        _ = sc.packed  # pack once (a cached property), before the threads share it
    effects = CameraEffects() if effects is None else effects
    timings = {}

    def view(camera):
        P, D = (rig.P_left, rig.D_left) if camera == "left" else (rig.P_right, rig.D_right)
        t0 = time.perf_counter()
        out = render_view(scenes[camera], P, D, rig.image_size, supersample=supersample, tile_size=tile_size,
                          model=rig.distortion_model)
        timings[camera] = time.perf_counter() - t0
        return out

    with ThreadPoolExecutor(max_workers=2) as pool:  # the kernels release the GIL
        views = list(pool.map(view, ("left", "right")))
    t0 = time.perf_counter()
    rng = np.random.default_rng([int(scene.seed) & 0x7FFFFFFF, int(scene.frame), 0x5E25])
    images = [effects.expose(v.radiance, cam, rng) for cam, v in enumerate(views)]
    cams = (scenes["left"], scenes["right"])  # index -1 (no hit) -> the appended 0
    leaf_ids = [np.append(sc.packed.leaf_ids, 0).astype(np.uint16)[v.prim_index] for sc, v in zip(cams, views)]
    labels = [np.append(sc.packed.labels, 0).astype(np.uint8)[v.prim_index] for sc, v in zip(cams, views)]
    plants = [np.append(sc.plant_of_primitive(), 0).astype(np.uint16)[v.prim_index] for sc, v in zip(cams, views)]
    truth = scene.truth()
    n_ids = max(int(sc.packed.leaf_ids.max(initial=0)) for sc in cams) + 1
    counts = [np.bincount(ids.ravel(), minlength=n_ids) for ids in leaf_ids]
    for lf in truth["leaves"]:
        lf["pixels_left"] = int(counts[0][lf["id"]])
        lf["pixels_right"] = int(counts[1][lf["id"]])
    truth["image_size"] = list(rig.image_size)
    truth["supersample"] = int(supersample)
    truth["camera_effects"] = effects.as_dict()
    timings["sensor"] = time.perf_counter() - t0
    return SimResult(scene=scene, rig=rig, left=images[0], right=images[1],
                     xyz_left=views[0].xyz, xyz_right=views[1].xyz,
                     leaf_ids_left=leaf_ids[0], leaf_ids_right=leaf_ids[1],
                     labels_left=labels[0], labels_right=labels[1], truth=truth, timings=timings,
                     plants_left=plants[0], plants_right=plants[1])


def first_hits(scene: Scene, origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """First surface hit by each ray: ``(t (N,), primitive index (N,))``.

    ``origins`` (N, 3) or (3,), ``directions`` (N, 3) (normalised here), world
    frame; ``t`` is the distance in world units (inf on a miss) and the index
    points into ``scene.posed`` (-1 on a miss). Use it for visibility checks,
    e.g. whether a point seen by one camera is occluded in the other.
    """
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(np.asarray(origins, np.float64).reshape(-1, 3), d.shape).copy()
    packed = scene.packed
    return trace_rays(o, d, packed.kinds, packed.axes, packed.origins, packed.geometry)


def visible_from(scene: Scene, P, points, *, tolerance: float | None = None) -> np.ndarray:
    """(N,) bool: world points (N, 3) not occluded from the camera centre of ``P``.

    A point is visible when the first hit along the ray from the camera centre
    towards it lies within ``tolerance`` (default 1e-6 of the distance) of it.
    NaN points are not visible.
    """
    X = np.asarray(points, np.float64).reshape(-1, 3)
    C = camera_centre(P)
    vec = X - C
    dist = np.linalg.norm(vec, axis=1)
    ok = np.all(np.isfinite(X), axis=1) & (dist > 0)
    out = np.zeros(len(X), bool)
    if not np.any(ok):
        return out
    t, _ = first_hits(scene, C, vec[ok])
    tol = 1e-6 * dist[ok] if tolerance is None else tolerance
    out[ok] = t >= dist[ok] - tol
    return out
