"""Multi-view sequences of a synthetic plant with true rig poses (fusion ground truth).

The world frame is the rig file's frame with the plant as placed for view 0
(:func:`~canopy_stereo.sim.simulate.scene_for_rig`). View ``i`` has a true rig
pose ``T_i`` (4x4, rig frame -> world), so a cloud reconstructed from its
images in the rig's frame maps to the world by ``T_i``. Two modes:

* ``"turntable"``: the rig stands still and the plant turns on a turntable
  about its vertical axis (the pot's axis) by ``360 i / n`` degrees; the rig's
  pose is the opposite rotation (:func:`~canopy_stereo.fusion.poses.turntable_pose`).
* ``"orbit"``: the rig circles the plant about the same axis at an elevation,
  looking down on it by ``elevation_deg``.

Rendering is the same in both modes: the plant's primitives are moved by
``T_i^-1`` into the rig's frame and ray-cast with
:func:`~canopy_stereo.sim.render.render_pair`. The backdrop and the light stay
fixed relative to the rig (a turntable in front of a studio backdrop; for the
orbit, a backdrop carried behind the plant as in a photo box), so the backdrop
is never part of the plant: each view's ``mask`` (plant, pot and soil pixels of
the left image, from the true labels) stands in for the segmentation step.

API::

    seq = render_views("croton", rig=None, n_views=8, mode="turntable", seed=0)
    seq.views[i].pose        # (4, 4) true rig -> world
    seq.views[i].sim         # SimResult in the rig frame (left, right, xyz_left, labels, ...)
    seq.views[i].mask        # (H, W) uint8, 255 = plant/pot/soil
    seq.views[i].xyz_world() # true world points of the left pixels
    truth = sample_leaf_surfaces(seq.scene, spacing=1.0)   # true leaf surface samples (world)
    write_views(seq, "out/views")   # view_00/{left,right,mask}.png, rig.yaml; poses_true.yaml
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.poses import turntable_pose, write_poses
from canopy_stereo.geometry.transforms import invert_transform, rotation_about_line, transform_points
from canopy_stereo.io.rig import Rig
from canopy_stereo.sim import leaf as leafgeom
from canopy_stereo.sim.primitives import LABEL_BACKGROUND, LABEL_NONE, Frustum
from canopy_stereo.sim.render import SimResult, render_pair
from canopy_stereo.sim.scene import Scene, rig_anchor
from canopy_stereo.sim.simulate import resolve_rig, scene_for_rig

MODES = ("turntable", "orbit")


@dataclass
class SimView:
    """One rendered view of a sequence.

    Attributes:
        index: position in the sequence.
        name: ``view_00``, ``view_01``, ...
        pose: (4, 4) true rig frame -> world transform.
        sim: the :class:`SimResult` in the rig's frame (images, per-pixel truth).
        mask: (H, W) uint8 foreground of the left image (255 = plant, pot, soil).
    """

    index: int
    name: str
    pose: np.ndarray
    sim: SimResult
    mask: np.ndarray

    def xyz_world(self) -> np.ndarray:
        """(H, W, 3) true world points of the left image's pixels (NaN where none)."""
        return transform_points(self.pose, self.sim.xyz_left)


@dataclass
class MultiViewSequence:
    """A multi-view sequence.

    Attributes:
        scene: the plant in the world frame (view 0's placement).
        rig: the rig every view was taken with.
        mode: ``"turntable"`` or ``"orbit"``.
        views: the :class:`SimView` list.
        axis_point, axis_direction: the vertical axis the views turn about (world).
        centre: (3,) point on the axis at the height of the leaves (world).
        elevation_deg: the rig's elevation (orbit mode; 0 for the turntable).
    """

    scene: Scene
    rig: Rig
    mode: str
    views: list
    axis_point: np.ndarray
    axis_direction: np.ndarray
    centre: np.ndarray
    elevation_deg: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def poses(self) -> list:
        """True poses of the rendered views (list of (4, 4), in the order of :attr:`views`)."""
        return [v.pose for v in self.views]


def plant_axis(scene: Scene, rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(axis_point, axis_direction, centre)`` of a placed scene, world frame.

    The axis is the pot's axis (pointing up, out of the pot) when the scene has
    a pot, otherwise the rig's up direction through the leaves' centroid;
    ``centre`` is the point of the axis level with the leaves' centroid.
    """
    _, anchor_axes = rig_anchor(rig)
    up = -anchor_axes[1]
    pots = [p for p in scene.primitives if isinstance(p, Frustum)]
    leaves = scene.leaves
    if not leaves:
        raise CanopyStereoError(f"scene {scene.name!r} has no leaves to turn about")
    centroid = np.mean([lf.base for lf in leaves] + [lf.tip for lf in leaves], axis=0)
    if pots:
        pot = pots[0]
        point, direction = pot.base, pot.axis if pot.axis @ up > 0 else -pot.axis
    else:
        point, direction = centroid, up
    direction = direction / np.linalg.norm(direction)
    centre = point + ((centroid - point) @ direction) * direction
    return np.asarray(point, np.float64), direction, centre


def sequence_poses(n_views: int, mode: str, centre, axis_direction, rig, *, elevation_deg: float = 0.0,
                   start_deg: float = 0.0) -> list[np.ndarray]:
    """True rig poses (list of (4, 4), rig -> world) of an evenly spaced sequence.

    ``turntable``: the plant turns by ``start + 360 i / n`` degrees about the
    axis through ``centre``. ``orbit``: the rig turns about that axis by the same
    angles after rising by ``elevation_deg`` about the horizontal line through
    ``centre`` (so it looks down on the plant).
    """
    if mode not in MODES:
        raise CanopyStereoError(f"unknown sequence mode {mode!r}; choose {' or '.join(MODES)}")
    if n_views < 1:
        raise CanopyStereoError(f"need at least one view, got {n_views}")
    axis = np.asarray(axis_direction, np.float64)
    c = np.asarray(centre, np.float64)
    angles = start_deg + 360.0 * np.arange(n_views) / n_views
    if mode == "turntable":
        return [turntable_pose(a, c, axis) for a in angles]
    origin, anchor_axes = rig_anchor(rig)
    side = np.cross(axis, origin - c)
    side /= np.linalg.norm(side)
    rise = rotation_about_line(c, side, np.radians(elevation_deg))
    if (transform_points(rise, origin) - origin) @ axis < 0:
        rise = rotation_about_line(c, side, -np.radians(elevation_deg))
    return [rotation_about_line(c, axis, np.radians(a)) @ rise for a in angles]


def _moved_scene(scene: Scene, M, seed: int) -> Scene:
    """The scene with every primitive but the backdrop moved by the rigid ``M`` (4, 4)."""
    Q, t = M[:3, :3], M[:3, 3]
    prims = tuple(p if p is scene.background else p.transformed(Q, t, 1.0) for p in scene.primitives)
    breeze = {k: replace(b, axis=Q @ b.axis) for k, b in scene.breeze.items()}
    return replace(scene, primitives=prims, breeze=breeze, seed=seed)


def foreground_mask(sim: SimResult) -> np.ndarray:
    """(H, W) uint8: 255 where the left pixel sees the plant, pot or soil (not backdrop/nothing)."""
    lab = sim.labels_left
    return np.where((lab != LABEL_BACKGROUND) & (lab != LABEL_NONE), 255, 0).astype(np.uint8)


def render_views(scene="croton", rig=None, *, n_views: int = 8, mode: str = "turntable", seed: int = 0,
                 elevation_deg: float | None = None, start_deg: float = 0.0, supersample: int = 2,
                 effects=None, indices=None, progress=None) -> MultiViewSequence:
    """Render a multi-view sequence of a plant with true poses.

    Args:
        scene: a scene name (:data:`~canopy_stereo.sim.SCENES`) or a
            :class:`Scene` already placed in the rig's world frame.
        rig: a Rig, a rig file path, or None (``config/paper_rig.yaml``).
        n_views: number of views, evenly spaced over 360 degrees.
        mode: ``"turntable"`` (plant turns) or ``"orbit"`` (rig circles, looking down).
        seed: scene layout seed (for a name) and per-view sensor noise.
        elevation_deg: orbit elevation (default 20; must be 0 or absent for the turntable).
        progress: optional ``f(view name)`` called after each view is rendered.
        start_deg: angle of view 0.
        supersample, effects: passed to :func:`~canopy_stereo.sim.render.render_pair`.
        indices: render only these views of the ``n_views`` sequence (default all).

    Returns:
        :class:`MultiViewSequence`; view 0 of a turntable with ``start_deg = 0``
        has the identity pose.
    """
    rig = resolve_rig(rig)
    placed = scene_for_rig(scene, rig, seed=seed) if isinstance(scene, str) else scene
    if placed.world_unit != rig.world_unit:
        raise CanopyStereoError(f"scene is in {placed.world_unit} but the rig in {rig.world_unit}")
    if mode == "turntable":
        if elevation_deg:
            raise CanopyStereoError("a turntable sequence has no elevation (the rig does not move)")
        elevation = 0.0
    else:
        elevation = 20.0 if elevation_deg is None else float(elevation_deg)
    point, direction, centre = plant_axis(placed, rig)
    poses = sequence_poses(n_views, mode, centre, direction, rig, elevation_deg=elevation, start_deg=start_deg)
    views = []
    wanted = range(n_views) if indices is None else sorted({int(i) for i in indices})
    for i in wanted:
        if not 0 <= i < n_views:
            raise CanopyStereoError(f"view index {i} is outside the {n_views}-view sequence")
        T = poses[i]
        moved = _moved_scene(placed, invert_transform(T), seed=int(seed) * 1000 + i)
        sim = render_pair(moved, rig, supersample=supersample, effects=effects)
        views.append(SimView(index=i, name=f"view_{i:02d}", pose=T, sim=sim, mask=foreground_mask(sim)))
        if progress is not None:
            progress(f"view_{i:02d}")
    return MultiViewSequence(scene=placed, rig=rig, mode=mode, views=views, axis_point=point,
                             axis_direction=direction, centre=centre, elevation_deg=elevation)


def sample_leaf_surfaces(scene: Scene, spacing: float = 1.0, *, leaf_ids=None) -> tuple[np.ndarray, np.ndarray]:
    """Samples of the true leaf blades on a grid of ``spacing`` in each blade's frame.

    Args:
        scene: a placed scene (world frame).
        spacing: grid step along and across the midrib (world units); the
            samples are about evenly spread over the area (the blades' slopes
            stretch the area by a few per cent at most).
        leaf_ids: only these leaves (default all).

    Returns:
        ``(points (N, 3) world, leaf_ids (N,) int)``.
    """
    pts, ids = [], []
    for lf in scene.leaves:
        if leaf_ids is not None and lf.leaf_id not in leaf_ids:
            continue
        hw = lf.half_width
        x = np.arange(spacing / 2, lf.span, spacing)
        y = np.arange(-hw + spacing / 2, hw, spacing)
        gx, gy = np.meshgrid(x, y, indexing="ij")
        half = leafgeom.half_width_at(gx / lf.span, hw, lf.base_exponent, lf.tip_exponent)
        inside = np.abs(gy) <= half
        gx, gy = gx[inside], gy[inside]
        gz = leafgeom.surface_height(gx, gy, lf.droop, lf.rise, lf.cup)
        pts.append(lf.to_world(np.stack([gx, gy, gz], axis=1)))
        ids.append(np.full(len(gx), lf.leaf_id, np.int64))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(pts), np.concatenate(ids)


def write_views(seq: MultiViewSequence, out_dir) -> Path:
    """Write a sequence for ``canopy-stereo fuse``.

    Layout: ``out_dir/view_XX/{left.png, right.png, mask.png, rig.yaml}`` per
    view, ``out_dir/poses_true.yaml`` (the true poses, :mod:`canopy_stereo.fusion.poses`
    format) and ``out_dir/truth.json`` (scene truth, mode, axis, per-view poses).
    The views carry no ``pose.yaml``, so ``fuse`` registers them unless given
    ``--poses out_dir/poses_true.yaml``.
    """
    from canopy_stereo.io.images import write_image
    from canopy_stereo.io.rig import save_rig

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for v in seq.views:
        d = out / v.name
        d.mkdir(parents=True, exist_ok=True)
        write_image(d / "left.png", v.sim.left)
        write_image(d / "right.png", v.sim.right)
        write_image(d / "mask.png", v.mask)
        save_rig(seq.rig, d / "rig.yaml", comment=f"rig of {v.name} (synthetic {seq.scene.name}, {seq.mode})")
    write_poses(out / "poses_true.yaml", {v.name: v.pose for v in seq.views}, seq.rig.world_unit,
                comment=f"true rig poses (rig frame -> world) of the synthetic {seq.mode} sequence")
    truth = {"scene": seq.scene.truth(), "mode": seq.mode, "elevation_deg": seq.elevation_deg,
             "axis_point": seq.axis_point.tolist(), "axis_direction": seq.axis_direction.tolist(),
             "centre": seq.centre.tolist(),
             "views": [{"name": v.name, "pose": v.pose.tolist(),
                        "leaf_pixels_left": int((v.sim.leaf_ids_left > 0).sum())} for v in seq.views]}
    (out / "truth.json").write_text(json.dumps(truth, indent=1), encoding="utf-8")
    return out


def downscaled_rig(rig: Rig, factor: int) -> Rig:
    """The rig with images ``factor`` times smaller (same cameras, fewer pixels).

    Pixel centres keep the convention ``(0, 0)`` = centre of the top-left pixel:
    ``u' = (u + 0.5) / factor - 0.5``. Used to keep tests and previews small.
    """
    f = int(factor)
    if f < 1:
        raise CanopyStereoError(f"downscale factor must be a positive integer, got {factor}")
    if f == 1:
        return rig
    w, h = rig.image_size
    if w % f or h % f:
        raise CanopyStereoError(f"image size {w}x{h} is not divisible by {f}")
    if rig.has_distortion:
        raise CanopyStereoError("downscaling a rig with lens distortion is not supported")
    S = np.array([[1.0 / f, 0.0, 0.5 / f - 0.5], [0.0, 1.0 / f, 0.5 / f - 0.5], [0.0, 0.0, 1.0]])
    return replace(rig, P_left=S @ rig.P_left, P_right=S @ rig.P_right, image_size=(w // f, h // f))
