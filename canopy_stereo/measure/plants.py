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
#: Width (pixels) of the ring around the plants that is not taken for their container.
RING_PX = 4
#: A plant pixel whose point lies farther from the camera than the plant's median distance
#: plus this fraction of it is background seen through the mask's edge (dropped).
MAX_BEHIND_FRACTION = 0.2


def reference_surface(organized: np.ndarray, plant: np.ndarray, others: np.ndarray, frame: MeasuringFrame,
                      plant_points: np.ndarray, *, scale: float) -> dict:
    """The surface a plant's height is measured from, in ``frame`` (z up).

    Container points are the points that belong to no plant, lie within the plant's
    horizontal reach of the foot of the plant (the centre of its lowest 5 % of
    points; reach: the larger of half its height and the 90th percentile of its
    points' horizontal distances from the foot) and from 60 % of the plant's height (or
    four times its reach: a top view sees the leaves, not the stem down to the soil) below
    its foot to 10 % above, lie more than :data:`RING_PX` pixels from every plant, and
    are not on the ground plane. Their 98th percentile height is the reference:
    ``pot_rim`` when the container stands more than 3 % of the plant's height (a pot
    wall), else ``soil``; without container
    points the ground plane (``ground``, height 0), else ``none`` (the plant's lowest point).

    Args:
        organized: (H, W, 3) world points.
        plant, others: (H, W) bool pixels of this plant and of every other plant.
        frame: the plant's measuring frame.
        plant_points: (N, 3) world points of the plant's canopy.
        scale: typical distance to the scene (world units; the ground tolerance is 1 %).

    Returns ``{"kind", "height" (frame z of the surface, world units), "height_above_ground"
    (or None without a ground plane), "n_points"}``.
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
    if len(C) >= MIN_CONTAINER_POINTS:
        top = float(np.percentile(C[:, 2], 98))
        span = top - float(np.percentile(C[:, 2], 5))
        kind = "pot_rim" if span > 0.03 * height else "soil"
        return {"kind": kind, "height": top, "height_above_ground": top if has_ground else None,
                "n_points": int(len(C))}
    if has_ground:
        return {"kind": "ground", "height": 0.0, "height_above_ground": 0.0, "n_points": int(frame.ground_inliers)}
    return {"kind": "none", "height": float(z.min()), "height_above_ground": None, "n_points": 0}


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
    plus ``plant_index`` and ``reference`` (:func:`reference_surface`); its
    ``canopy["height"]`` is the top of the plant above the reference surface (world
    units) and ``canopy["extent_height"]`` the plant's own vertical extent. With
    ``ground="auto"`` the ground plane is found once for the scene; each plant is measured
    on the part of the cloud around it, without the pixels whose points lie more than
    :data:`MAX_BEHIND_FRACTION` beyond its median distance (background seen through the
    mask's edge). A plant that cannot be measured gets ``{"plant_index", "error"}``.
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
            plants.append({"plant_index": k, "error": str(exc)})
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
        top = float(canopy["bbox_max"][2])
        canopy["extent_height"] = canopy["height"]
        canopy["height"] = top - ref["height"] if ref["kind"] != "none" else canopy["height"]
        plants.append({"plant_index": k, "reference": ref, **report})
    return {"n_plants": len(plants), "unit": unit, "plants": plants}


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


def _trimmed(organized, finite, mask, P):
    """``mask`` without pixels whose points lie far behind the plant (background at its edges)."""
    if P is None or not (mask & finite).any():
        return mask
    dist = np.linalg.norm(organized - camera_centre(P), axis=-1)
    med = float(np.median(dist[mask & finite]))
    with np.errstate(invalid="ignore"):
        return mask & ~(dist > (1.0 + MAX_BEHIND_FRACTION) * med)


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
