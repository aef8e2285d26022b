"""Measuring one scene: leaves and canopy of a cloud, as the REPORT.json dict.

:func:`measure_scene` (organized clouds) and :func:`measure_points` (unorganized
ones) check the input, separate or take the leaves, measure each leaf
(:mod:`~canopy_stereo.measure.leaf`), clean the canopy
(:mod:`~canopy_stereo.measure.cleaning`), set up the measuring frame
(:mod:`~canopy_stereo.measure.frame`) and measure the canopy
(:mod:`~canopy_stereo.measure.canopy`). The report's layout is described in
:mod:`canopy_stereo.measure.report`, which also writes it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.geometry.clouds import check_cloud, check_on_grid
from canopy_stereo.measure.canopy import canopy_dimensions
from canopy_stereo.measure.cleaning import (
    clean_canopy,
    drop_detached_clusters,
    drop_isolated_points,
    median_along_rays,
)
from canopy_stereo.measure.frame import MeasuringFrame, image_directions, measuring_frame
from canopy_stereo.measure.instances import separate_leaves
from canopy_stereo.measure.leaf import measure_leaf
from canopy_stereo.measure.surface import roughness
from canopy_stereo.measure.viewpoint import resolve_camera

#: Leaves seen more obliquely than this (70 degrees; nearly edge-on) add their cleaned raw
#: points to the canopy of a reconstruction instead of their fitted surface,
#: which is poorly determined along the line of sight.
MAX_SURFACE_VIEW_ANGLE_DEG = 70.0


#: Roughness (pixel sizes, depth jumps left out: :func:`~canopy_stereo.measure.surface.roughness`)
#: below which a plant's cloud is exact (rendered) and not cleaned: rendered seedlings measure
#: 0.003-0.025 with the background pixels an automatic mask takes at their edges, stereo
#: clouds of the same seedlings 0.18 and more (ELAS).
EXACT_CLOUD_ROUGHNESS = 0.05

#: Cell edge, as a fraction of the canopy's size, of the clustering that drops
#: stray matches detached from the canopy (:func:`drop_detached_clusters`).
DETACHED_CELL_FRACTION = 0.04


@dataclass
class SceneMeasurement:
    """Everything measured in one cloud.

    Attributes:
        report: the REPORT.json dict.
        canopy_points: (N, 3) world points counted as canopy.
        frame: the :class:`MeasuringFrame` of the canopy extents.
        leaf_ids: (H, W) int32 leaf ids used (None for unorganized clouds).
    """

    report: dict
    canopy_points: np.ndarray
    frame: MeasuringFrame
    leaf_ids: np.ndarray | None = None


def check_organized(organized, *, name: str = "organized cloud") -> np.ndarray:
    """``organized`` as float64 (H, W, 3) (at least 2 x 2, :func:`~canopy_stereo.geometry.clouds.check_cloud`)
    with at least 3 valid points, or :class:`CanopyStereoError`."""
    arr = check_cloud(organized, name=name, min_size=2)
    n = int(np.all(np.isfinite(arr), axis=-1).sum())
    if n < 3:
        raise CanopyStereoError(f"the cloud has {n} valid 3D points; need at least 3 to measure anything")
    return arr


def _check_image_grid(img, organized: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(img)
    if arr.ndim == 3:
        if arr.shape[2] == 1 or np.all(arr == arr[..., :1]):
            arr = arr[..., 0]
        else:
            raise CanopyStereoError(f"{name} must be a single-channel image, got shape {arr.shape}")
    if arr.ndim != 2:
        raise CanopyStereoError(f"{name} must be an (H, W) image, got shape {arr.shape}")
    check_on_grid(arr, organized, name, hint="it must be drawn on the original left image")
    return arr


def measure_scene(organized, leaf_ids=None, *, mask=None, ground="auto", unit: str = "mm",
                  camera="auto", voxel_size: float | None = None, separate: bool = True,
                  min_leaf_pixels: int = 100, model: str = "auto", degree: int = 2,
                  smoothing_px: float = 2.0) -> SceneMeasurement:
    """Measure leaves and canopy in an organized cloud.

    Args:
        organized: (H, W, 3) world points of the left image's pixels, NaN where none.
        leaf_ids: optional (H, W) integer image, 0 = not a leaf, else the leaf's id.
        mask: optional (H, W) plant mask (nonzero = plant). Without ``leaf_ids``
            its leaves are separated automatically (``separate``); with both,
            the canopy is the mask and the leaves are the ids.
            With neither, every point is canopy and no leaf is measured.
        ground: see :func:`measuring_frame`.
        unit: world unit of the cloud (for the report).
        camera: left camera ``P`` (3, 4), ``"auto"`` (estimate it from the
            cloud) or None. It lets leaves be smoothed along viewing rays.
        voxel_size: voxel edge for the occupancy volume (default: a round
            number near the largest extent / 50).
        separate: split a plant mask into leaves when no ids are given.
        min_leaf_pixels: smaller leaves are listed under ``skipped_leaves``.
        model, degree, smoothing_px: leaf surface model (see
            :func:`~canopy_stereo.measure.leaf.measure_leaf`).
    """
    organized = check_organized(organized)
    finite = np.all(np.isfinite(organized), axis=-1)
    h, w = organized.shape[:2]
    ids = None if leaf_ids is None else _check_image_grid(leaf_ids, organized, "leaf-id image")
    plant = None if mask is None else _check_image_grid(mask, organized, "mask").astype(bool)
    if ids is not None and not np.issubdtype(ids.dtype, np.integer):
        if not np.all(np.mod(ids, 1) == 0):
            raise CanopyStereoError("leaf-id image must hold integer ids")
        ids = ids.astype(np.int64)
    if plant is not None and not plant.any():
        raise CanopyStereoError("the mask is empty: no plant pixel to measure")
    if ids is not None and not np.any(ids != 0):
        raise CanopyStereoError("the leaf-id image has no leaf (all pixels are 0)")
    if plant is None and ids is not None:
        plant = ids != 0
    source = {"image_size": [int(w), int(h)], "points": int(finite.sum()),
              "leaf_ids": "given" if ids is not None else ("separated" if (plant is not None and separate)
                                                           else "none"),
              "mask": "given" if mask is not None else ("from leaf ids" if ids is not None else "none")}
    if plant is not None and int((plant & finite).sum()) < 3:
        raise CanopyStereoError(f"only {int((plant & finite).sum())} plant pixels have a 3D point; "
                                "need at least 3")

    cam_given = camera is not None and not isinstance(camera, str)
    P = resolve_camera(camera, organized)
    source["camera"] = "given" if cam_given else ("estimated" if P is not None else "none")
    if P is not None:
        source["camera_centre"] = [float(v) for v in camera_centre(P)]

    if ids is None and plant is not None and separate:
        ids = separate_leaves(organized, plant,
                              min_pixels=max(10, min_leaf_pixels // 2))
    all_plant = (plant if plant is not None else finite) & finite
    exact_cloud = bool(all_plant.sum() >= 16
                       and roughness(organized, all_plant, skip_jumps=True) < EXACT_CLOUD_ROUGHNESS)
    leaves, skipped = [], []
    leaf_surfaces: list = []  # (N, 3) surface points of the leaves kept
    in_leaf = np.zeros((h, w), bool)
    rejected = np.zeros((h, w), bool)  # leaf points its surface fit found to be matching errors
    if ids is not None:
        values, counts = np.unique(ids[ids != 0], return_counts=True)
        for value, count in zip(values.tolist(), counts.tolist()):
            if count < min_leaf_pixels:
                skipped.append({"id": int(value), "reason": f"{count} pixels (< {min_leaf_pixels})"})
                continue
            leaf_mask = ids == value
            try:
                lm = measure_leaf(organized, leaf_mask, leaf_id=int(value), camera=P, model=model,
                                  degree=degree, smoothing_px=smoothing_px)
            except CanopyStereoError as exc:
                skipped.append({"id": int(value), "reason": str(exc)})
                continue
            leaves.append(lm.to_dict())
            if lm.outlier_mask is not None and not exact_cloud:
                rejected |= lm.outlier_mask
            if plant is not None and (leaf_mask & plant).sum() < 0.5 * count:
                continue  # a leaf outside the given plant mask is not canopy
            angle = lm.extra.get("view_angle_deg")
            if angle is None or angle <= MAX_SURFACE_VIEW_ANGLE_DEG or exact_cloud:
                leaf_surfaces.append(lm.surface_points)
                in_leaf |= leaf_mask

    # canopy points: the fitted surfaces of the measured leaves (free of matching
    # noise, which would widen the extents) and the other plant points, cleaned
    plant_valid = (plant if plant is not None else finite) & finite & ~in_leaf & ~rejected
    rest_pts = np.zeros((0, 3))
    if plant_valid.sum() >= 3:
        if exact_cloud:  # a rendered cloud: nothing to clean
            rest_pts = organized[plant_valid]
        else:
            background_mask = None if plant is None else (finite & ~plant)
            viewpoint = None if P is None else camera_centre(P)
            kept = clean_canopy(organized, plant_valid, background=background_mask, viewpoint=viewpoint,
                                all_plant=all_plant)
            rest_pts = drop_isolated_points(median_along_rays(organized, kept, viewpoint)
                                            if viewpoint is not None else organized[kept])
    canopy_pts = np.concatenate(leaf_surfaces + [rest_pts])
    if not exact_cloud and len(canopy_pts) >= 10:
        span = float(np.max(np.percentile(canopy_pts, 99, axis=0) - np.percentile(canopy_pts, 1, axis=0)))
        is_rest = np.zeros(len(canopy_pts), bool)
        is_rest[len(canopy_pts) - len(rest_pts):] = True
        canopy_pts = canopy_pts[drop_detached_clusters(canopy_pts, DETACHED_CELL_FRACTION * span,
                                                       candidates=is_rest)]
    if len(canopy_pts) < 3:
        raise CanopyStereoError(f"the canopy has {len(canopy_pts)} usable 3D points; need at least 3")
    background = organized[finite & ~(plant if plant is not None else np.zeros_like(finite))]
    right, down, view = image_directions(organized, finite, P)
    if P is not None:
        scale = float(np.median(np.linalg.norm(canopy_pts - camera_centre(P), axis=1)))
    else:
        scale = float(np.linalg.norm(np.ptp(organized[finite], axis=0)))
    if plant is None and ground == "auto":
        # no mask: the ground is whatever plane the scene stands on; the rest is canopy
        frame = measuring_frame(canopy_pts, canopy_pts, ground, right, down, view, scale)
        if frame.ground_plane is not None:
            above = canopy_pts @ frame.ground_plane[:3] + frame.ground_plane[3] > 0.01 * scale
            if above.sum() >= 3:
                canopy_pts = canopy_pts[above]
    else:
        frame = measuring_frame(canopy_pts, background, ground, right, down, view, scale)
    leaf_area = float(sum(lf["area"] for lf in leaves)) if leaves else None
    canopy = canopy_dimensions(canopy_pts, frame, voxel_size=voxel_size, leaf_area=leaf_area)
    canopy["n_leaves"] = len(leaves)
    report = {"unit": unit, "units": _units(unit), "source": source, "frame": frame.to_dict(),
              "leaves": leaves, "skipped_leaves": skipped, "canopy": canopy}
    return SceneMeasurement(report=report, canopy_points=canopy_pts, frame=frame,
                            leaf_ids=None if ids is None else np.asarray(ids))


def measure_organized(organized, leaf_ids=None, *, mask=None, ground="auto", unit: str = "mm",
                      camera="auto", voxel_size: float | None = None, **options) -> dict:
    """The REPORT.json dict of an organized cloud (see :func:`measure_scene`)."""
    return measure_scene(organized, leaf_ids=leaf_ids, mask=mask, ground=ground, unit=unit,
                         camera=camera, voxel_size=voxel_size, **options).report


def measure_points(points, ground="auto", *, unit: str = "mm", voxel_size: float | None = None,
                   up=(0.0, -1.0, 0.0), right=(1.0, 0.0, 0.0)) -> SceneMeasurement:
    """Canopy size of an unorganized cloud (e.g. a PLY file); no per-leaf sizes.

    Without a pixel grid there is no image direction: ``up`` and ``right``
    give the world's up and right (default: the rigs' convention, world +Y
    roughly image-down, +X right). With ``ground="auto"`` a ground plane
    within 35 degrees of ``up`` is searched among all points and the points
    on it are not canopy.
    """
    P = check_cloud(points, organized=None, name="point cloud").reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    if len(P) < 3:
        raise CanopyStereoError(f"the cloud has {len(P)} valid 3D points; need at least 3 to measure anything")
    up = np.asarray(up, np.float64)
    right = np.asarray(right, np.float64)
    view = np.cross(right, -up)
    scale = float(np.linalg.norm(np.ptp(P, axis=0)))
    frame = measuring_frame(P, P, ground, right, -up, view, scale)
    canopy_pts = P
    if frame.kind == "ground":
        assert frame.ground_plane is not None  # (a ground frame has its plane)
        above = P @ frame.ground_plane[:3] + frame.ground_plane[3] > 0.01 * scale
        if above.sum() >= 3:
            canopy_pts = P[above]
    canopy = canopy_dimensions(canopy_pts, frame, voxel_size=voxel_size)
    canopy["n_leaves"] = 0
    report = {"unit": unit, "units": _units(unit),
              "source": {"points": int(len(P)), "leaf_ids": "none", "mask": "none", "camera": "none"},
              "frame": frame.to_dict(), "leaves": [], "skipped_leaves": [], "canopy": canopy}
    return SceneMeasurement(report=report, canopy_points=canopy_pts, frame=frame)


def _units(unit: str) -> dict:
    return {"length": unit, "area": f"{unit}^2", "volume": f"{unit}^3", "leaf_area_density": f"1/{unit}"}
