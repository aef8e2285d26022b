"""Several plants per scene, each measured like a phenotyper does: height from the pot rim or soil.

:func:`measure_plants` measures each plant of a plant-instance image
(:func:`canopy_stereo.segmentation.segment_plants`) on its own with
:func:`~canopy_stereo.measure.scene.measure_scene` (its own points only: the pot,
the soil and the other plants are not its canopy), then finds its *reference
surface* (:func:`reference_surface`): the top of the container it grows from
(the pot rim; the soil of a tray), else the ground plane, else none, and
reports the plant's height as the top of its canopy above that surface.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.measure.frame import MeasuringFrame, image_directions, measuring_frame
from canopy_stereo.measure.scene import check_organized, measure_scene
from canopy_stereo.measure.viewpoint import resolve_camera

#: Reference surfaces, best first.
REFERENCE_KINDS = ("pot_rim", "soil", "ground", "none")
#: Fewest container points that make a reference surface.
MIN_CONTAINER_POINTS = 30
#: Steepest soil (degrees from the measuring frame's horizontal) taken as a plant's reference plane.
MAX_SOIL_TILT_DEG = 20.0
#: Width (pixels) of the ring around the plants that is not taken for their container.
RING_PX = 4
#: A plant pixel whose point lies farther from the camera than the plant's median distance
#: plus this fraction of it is suspect: background seen through the mask's edge, unless
#: :func:`_trimmed` finds it continuing the canopy (far-side leaves).
MAX_BEHIND_FRACTION = 0.2
#: Width (pixels) of the ring around a group of suspect pixels whose plant and background
#: distances the group is compared with.
FAR_RING_PX = 2
#: A group of suspect pixels is the plant's far side when it lies less than this share of the
#: way from the plant's distance around it to the background's (else: matching debris).
FAR_SIDE_SHARE = 1.0 / 3.0


def reference_surface(organized: np.ndarray, plant: np.ndarray, others: np.ndarray, frame: MeasuringFrame,
                      plant_points: np.ndarray, *, scale: float) -> dict:
    """The surface a plant's height is measured from, in ``frame`` (z up).

    Container points are the points that belong to no plant, lie within the plant's
    horizontal reach of the foot of the plant (the centre of its lowest 5 % of
    points; reach: the larger of half its height and the 90th percentile of its
    points' horizontal distances from the foot) and from 60 % of the plant's height (or
    four times its reach: a top view sees the leaves, not the stem down to the soil) below
    its foot to 10 % above, lie more than :data:`RING_PX` pixels from every plant, and
    are not on the ground plane. Without a ground plane (a top view: the frame's up is the
    view's), when they are flat (:func:`_soil_plane`: a plane holds 95 % of them within 3 %
    of the plant's height) that plane is the reference, ``soil``, and the plant's height is
    its top above the plane along the plane's normal (the soil of a tray seen from above
    need not face the camera squarely). Otherwise their 98th percentile height is the
    reference: ``pot_rim`` when the container stands more than 3 % of the plant's height (a
    pot wall), else ``soil``; without container points the ground plane (``ground``, height 0), else ``none`` (the
    plant's lowest point).

    Args:
        organized: (H, W, 3) world points.
        plant, others: (H, W) bool pixels of this plant and of every other plant.
        frame: the plant's measuring frame.
        plant_points: (N, 3) world points of the plant's canopy.
        scale: typical distance to the scene (world units; the ground tolerance is 1 %).

    Returns ``{"kind", "height" (frame z of the surface under the plant's foot, world units),
    "height_above_ground" (or None without a ground plane), "n_points", "plant_height" (the
    plant's top above the surface, world units; ``none``: the plant's own extent),
    "tilt_deg" (of the soil plane against the frame's horizontal; 0 otherwise)}``.
    """
    F = frame.to_frame(plant_points)
    z = F[:, 2]
    height = float(np.ptp(z)) if len(z) else 0.0
    low = F[z <= np.percentile(z, 5)]
    foot = np.median(low[:, :2], axis=0)
    foot_z = float(np.percentile(z, 2))
    reach = max(0.5 * height, float(np.percentile(np.linalg.norm(F[:, :2] - foot, axis=1), 90)))
    finite = np.all(np.isfinite(organized), axis=-1)
    # a ring around the plants is left out: the leaf edges a mask missed are not the container
    near = cv2.dilate((plant | others).astype(np.uint8), np.ones((2 * RING_PX + 1,) * 2, np.uint8)) > 0
    candidates = finite & ~near
    C = frame.to_frame(organized[candidates])
    keep = ((np.linalg.norm(C[:, :2] - foot, axis=1) <= reach)
            & (C[:, 2] >= foot_z - max(0.6 * height, 4.0 * reach)) & (C[:, 2] <= foot_z + 0.1 * height))
    has_ground = frame.ground_plane is not None
    if has_ground:
        keep &= C[:, 2] > 0.01 * scale
    C = C[keep]
    top_z = float(z.max()) if len(z) else 0.0
    if len(C) >= MIN_CONTAINER_POINTS:
        # without a ground plane, up is the view's or the image's: the soil's own plane is better
        soil = None if has_ground else _soil_plane(C, foot, height)
        if soil is not None:  # flat: soil (a tray seen from above may be tilted to the view)
            slope, offset = soil
            surface = float(offset + slope @ foot)
            above = F[:, 2] - (F[:, :2] @ slope + offset)
            return {"kind": "soil", "height": surface, "height_above_ground": surface if has_ground else None,
                    "n_points": int(len(C)), "plant_height": float(above.max()),
                    "tilt_deg": float(np.degrees(np.arctan(np.linalg.norm(slope))))}
        top = float(np.percentile(C[:, 2], 98))
        kind = "pot_rim" if top - float(np.percentile(C[:, 2], 5)) > 0.03 * height else "soil"
        return {"kind": kind, "height": top, "height_above_ground": top if has_ground else None,
                "n_points": int(len(C)), "plant_height": top_z - top, "tilt_deg": 0.0}
    if has_ground:
        return {"kind": "ground", "height": 0.0, "height_above_ground": 0.0, "n_points": int(frame.ground_inliers),
                "plant_height": top_z, "tilt_deg": 0.0}
    return {"kind": "none", "height": float(z.min()) if len(z) else 0.0, "height_above_ground": None, "n_points": 0,
            "plant_height": height, "tilt_deg": 0.0}


def _soil_plane(C: np.ndarray, foot: np.ndarray, height: float):
    """``(slope (2,), offset)`` of the plane ``z = slope . (x, y) + offset`` the container points
    ``C`` (N, 3, frame coordinates) lie on when they are flat soil: the least-squares plane of
    the points (refitted without those more than 3 % of the plant's ``height`` off it), tilted
    by at most :data:`MAX_SOIL_TILT_DEG`, that holds 95 % of them within 3 % of ``height``;
    else None (a pot: a rim above its soil)."""
    tol = 0.03 * height
    if not tol > 0:
        return None
    A = np.column_stack([C[:, 0] - foot[0], C[:, 1] - foot[1], np.ones(len(C))])
    use = np.ones(len(C), bool)
    for _ in range(3):
        if use.sum() < MIN_CONTAINER_POINTS:
            return None
        coef = np.linalg.lstsq(A[use], C[use, 2], rcond=None)[0]
        resid = np.abs(C[:, 2] - A @ coef)
        use = resid <= tol
    slope = coef[:2]
    if np.degrees(np.arctan(np.linalg.norm(slope))) > MAX_SOIL_TILT_DEG or use.mean() < 0.95:
        return None
    return slope, float(coef[2] - slope @ foot)


def measure_plants(organized, instances, *, ground="auto", unit: str = "mm", camera="auto",
                   voxel_size: float | None = None, **options) -> dict:
    """Measure each plant of a plant-instance image on its own.

    Args:
        organized: (H, W, 3) world points of the image's pixels (NaN = none).
        instances: (H, W) integer plant numbers (0 = not plant), e.g.
            ``segment_plants(...).instances``; plants are reported in increasing number.
        ground, unit, camera, voxel_size, options: as :func:`~canopy_stereo.measure.scene.measure_scene`
            (``ground="view"`` for top views such as a seedling tray).

    Returns ``{"n_plants": N, "unit": unit, "plants": [report, ...]}``: each report is
    :func:`~canopy_stereo.measure.scene.measure_scene`'s REPORT dict of that plant alone
    plus ``plant_index``, ``reference`` (:func:`reference_surface`) and ``at_image_border``
    (its pixels touch the image border: its top or its extents may lie out of view); its
    ``canopy["height"]`` is the top of the plant above the reference surface (world
    units) and ``canopy["extent_height"]`` the plant's own vertical extent. With
    ``ground="auto"`` the ground plane is found once for the scene; each plant is measured
    on the part of the cloud around it, without the background seen through the mask's edge
    (:func:`trimmed_mask`). A plant that cannot be measured gets ``{"plant_index", "error"
    (the one-line reason), "at_image_border"}`` and the others are measured as ever
    (:func:`~canopy_stereo.measure.plant.plant_summary` makes it the report's entry).
    Raises :class:`CanopyStereoError` when the image has no plant.
    """
    organized = check_organized(organized)
    inst = np.asarray(instances)
    if inst.ndim != 2 or inst.shape != organized.shape[:2]:
        raise CanopyStereoError(f"plant instances must be an (H, W) image like the cloud {organized.shape[:2]}, "
                                f"got shape {inst.shape}")
    if not np.issubdtype(inst.dtype, np.integer):
        raise CanopyStereoError(f"plant instances must hold integer plant numbers, got {inst.dtype}")
    numbers = [int(k) for k in np.unique(inst) if k > 0]
    if not numbers:
        raise CanopyStereoError("no plant to measure: the plant-instance image is all 0")
    P = resolve_camera(camera, organized)
    finite = np.all(np.isfinite(organized), axis=-1)
    plane = ground
    if isinstance(ground, str) and ground == "auto":  # one ground plane for all the plants
        plane = _scene_ground(organized, finite, inst > 0, P)
    plants = []
    for k in numbers:
        mask = _trimmed(organized, finite, inst == k, P)
        try:
            res = _measure_cropped(organized, mask, P, ground=plane, unit=unit, voxel_size=voxel_size,
                                   **options)
        except CanopyStereoError as exc:
            plants.append({"plant_index": k, "error": str(exc), "at_image_border": _at_border(inst == k)})
            continue
        if P is not None:
            scale = float(np.median(np.linalg.norm(res.canopy_points - camera_centre(P), axis=1)))
        else:
            scale = float(np.linalg.norm(np.ptp(res.canopy_points, axis=0)))
        ref = reference_surface(organized, inst == k, (inst > 0) & (inst != k), res.frame, res.canopy_points,
                                scale=scale)
        report = res.report
        if not isinstance(plane, str) and isinstance(ground, str):
            report["frame"]["kind"] = "ground"
        canopy = report["canopy"]
        canopy["extent_height"] = canopy["height"]
        canopy["height"] = ref["plant_height"]
        plants.append({"plant_index": k, "reference": ref, "at_image_border": _at_border(inst == k), **report})
    return {"n_plants": len(plants), "unit": unit, "plants": plants}


def _at_border(mask: np.ndarray) -> bool:
    """Whether a plant's pixels touch the image border (part of it may be out of view)."""
    return bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())


def _scene_ground(organized, finite, plants, P):
    """The scene's ground plane ``(a, b, c, d)`` found once among the non-plant points, or "auto"."""
    right, down, view = image_directions(organized, finite, P)
    canopy = organized[plants & finite]
    if len(canopy) < 3:
        return "auto"
    scale = (float(np.median(np.linalg.norm(canopy - camera_centre(P), axis=1))) if P is not None
             else float(np.linalg.norm(np.ptp(organized[finite], axis=0))))
    frame = measuring_frame(canopy, organized[finite & ~plants], "auto", right, down, view, scale)
    return "auto" if frame.ground_plane is None else frame.ground_plane


def trimmed_mask(organized: np.ndarray, mask: np.ndarray, *, camera) -> np.ndarray:
    """(H, W) bool: a plant's ``mask`` without the background seen through its edge
    (:func:`_trimmed`; ``camera``: ``P`` (3, 4), or None: the mask as it is). This is how
    :func:`measure_plants` measures each plant; the one measuring pipeline measures a
    lone plant so too."""
    organized = np.asarray(organized, np.float64)
    return _trimmed(organized, np.all(np.isfinite(organized), axis=-1), np.asarray(mask, bool), camera)


def _trimmed(organized, finite, mask, P):
    """``mask`` (H, W) bool without the pixels whose points are background seen through the
    plant's edge (``organized`` (H, W, 3) world points, ``finite`` their (H, W) validity,
    ``P`` (3, 4) the camera, or None: ``mask`` as it is).

    Suspect pixels lie farther from the camera centre than :data:`MAX_BEHIND_FRACTION`
    beyond the plant's median distance. They are grouped (8-connected) and each group is
    compared, by median distances, with the plant pixels that are not suspect and with the
    finite pixels outside the mask in a ring :data:`FAR_RING_PX` wide around it. A group is
    kept when it has plant pixels around it and lies less than :data:`FAR_SIDE_SHARE` of the
    way from their distance to the background's (or has no background around it): the far
    side of the canopy seen through a gap, which the matcher puts a little farther than it is
    (croton, 640x480: leaves 770-800 mm away measured 820-840 mm, plant around them 780-795,
    background 950-980). The others are dropped: leaf edges the matcher gave the
    background's depth or a blend of the leaf's and the background's (their distance near
    the background's, or between the two).
    """
    if P is None or not (mask & finite).any():
        return mask
    from scipy import ndimage

    dist = np.linalg.norm(organized - camera_centre(P), axis=-1)
    plant = mask & finite
    med = float(np.median(dist[plant]))
    with np.errstate(invalid="ignore"):
        far = plant & (dist > (1.0 + MAX_BEHIND_FRACTION) * med)
    if not far.any():
        return mask
    groups, n = ndimage.label(far, np.ones((3, 3), bool))
    around = ndimage.grey_dilation(groups, size=(2 * FAR_RING_PX + 1,) * 2)  # a ring pixel: one group's
    ring = (groups == 0) & (around > 0)
    own = _group_medians(dist, groups, n)
    near = _group_medians(dist, np.where(ring & plant & ~far, around, 0), n)
    behind = _group_medians(dist, np.where(ring & finite & ~mask, around, 0), n)
    with np.errstate(invalid="ignore"):
        debris = np.abs(behind - own) <= (1.0 / FAR_SIDE_SHARE - 1.0) * np.abs(own - near)
    keep = np.concatenate([[False], np.isfinite(near) & ~debris])
    return mask & ~(far & ~keep[groups])


def _group_medians(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """(n,) median of ``values`` over the pixels of each label 1..n of ``labels`` (same shape,
    0 = none); NaN for a label without pixels."""
    sel = labels > 0
    v, g = values[sel], labels[sel]
    order = np.lexsort((v, g))
    v = v[order]
    counts = np.bincount(g, minlength=n + 1)[1:]
    starts = np.cumsum(counts) - counts
    out = np.full(n, np.nan)
    has = counts > 0
    out[has] = 0.5 * (v[starts[has] + (counts[has] - 1) // 2] + v[starts[has] + counts[has] // 2])
    return out


def _measure_cropped(organized, mask, P, *, ground, **options):
    """:func:`measure_scene` of one plant on the part of the cloud around it (a quarter of its
    size as margin), with the camera moved to the crop."""
    vs, us = np.nonzero(mask)
    if not len(vs):
        raise CanopyStereoError("the plant has no pixel")
    h, w = mask.shape
    my, mx = max(8, (vs.max() - vs.min()) // 4), max(8, (us.max() - us.min()) // 4)
    y0, y1 = max(0, vs.min() - my), min(h, vs.max() + my + 1)
    x0, x1 = max(0, us.min() - mx), min(w, us.max() + mx + 1)
    camera = None
    if P is not None:
        camera = np.array([[1.0, 0, -x0], [0, 1.0, -y0], [0, 0, 1.0]]) @ P
    return measure_scene(organized[y0:y1, x0:x1], mask=mask[y0:y1, x0:x1], ground=ground, camera=camera,
                         **options)
