"""Measure a reconstruction: per-leaf sizes and canopy size, as a JSON-ready report.

REPORT.json layout (lengths in ``unit``, areas in ``unit``^2, volumes in ``unit``^3)::

    {"unit": "mm",
     "units": {"length": "mm", "area": "mm^2", "volume": "mm^3", "leaf_area_density": "1/mm"},
     "source": {...},                    # image size, points, camera, leaf ids / mask used
     "frame": {...},                     # measuring frame (see canopy.MeasuringFrame)
     "leaves": [{"id", "length", "width", "area", "normal", "centroid", "chord",
                 "ends", "width_ends", "plane_rms", "n_pixels", "n_points",
                 "complete", "touches_border", "surface_model", "outliers",
                 "view_angle_deg", "grazing_fraction", "reliable"}, ...],
     "skipped_leaves": [{"id", "reason"}, ...],
     "canopy": {"height", "width", "depth", "top_above_ground", "base_above_ground",
                "hull_volume", "voxel_volume", "voxel_size", "occupied_voxels",
                "leaf_area", "leaf_area_density", "bbox_min", "bbox_max",
                "centroid", "n_points"}}

With a leaf-id image, a leaf's ``id`` is its value in that image; with a plant
mask the leaves are separated automatically and numbered by decreasing size.
"""
from __future__ import annotations

import csv as _csv
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import camera_centre, decompose_projection
from canopy_stereo.io.ply import read_ply
from canopy_stereo.measure.canopy import MeasuringFrame, canopy_dimensions, find_ground, frame_from_up
from canopy_stereo.measure.instances import connected_surface_parts, neighbour_spacing, separate_leaves
from canopy_stereo.measure.leaf import EXACT_ROUGHNESS, measure_leaf, roughness
from canopy_stereo.measure.surface import local_linear_fit
from canopy_stereo.measure.viewpoint import resolve_camera

#: Columns of the per-leaf CSV.
CSV_COLUMNS = ["id", "length", "width", "area", "chord", "normal_x", "normal_y", "normal_z",
               "centroid_x", "centroid_y", "centroid_z", "plane_rms", "n_pixels", "n_points",
               "complete", "touches_border", "view_angle_deg", "reliable", "surface_model"]


#: Leaves seen more obliquely than this (70 degrees; nearly edge-on) add their cleaned raw
#: points to the canopy of a reconstruction instead of their fitted surface,
#: which is poorly determined along the line of sight.
MAX_SURFACE_VIEW_ANGLE_DEG = 70.0


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


def check_organized(organized) -> np.ndarray:
    """``organized`` as float64 (H, W, 3) or :class:`CanopyStereoError`."""
    try:
        arr = np.asarray(organized, dtype=np.float64)
    except (TypeError, ValueError):
        raise CanopyStereoError("organized cloud is not numeric") from None
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 2 or arr.shape[1] < 2:
        raise CanopyStereoError(f"organized cloud must be an (H, W, 3) array, got shape {arr.shape}")
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
    h, w = organized.shape[:2]
    if arr.shape != (h, w):
        raise CanopyStereoError(
            f"{name} is {arr.shape[1]}x{arr.shape[0]} but the organized cloud is {w}x{h} "
            "(it must be drawn on the original left image)")
    return arr


def _image_directions(organized, valid, camera):
    """World directions of image right, image down and the view, from the camera or the grid."""
    if camera is not None:
        R = decompose_projection(camera).R
        return R[0].copy(), R[1].copy(), R[2].copy()
    _, Xu, Xv = local_linear_fit(organized, valid, valid, 2.0)
    ok = valid & np.all(np.isfinite(Xu), -1) & np.all(np.isfinite(Xv), -1)
    if ok.sum() < 3:
        return np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0])
    with np.errstate(invalid="ignore", divide="ignore"):
        right = np.nanmean(Xu[ok] / np.linalg.norm(Xu[ok], axis=1, keepdims=True), axis=0)
        down = np.nanmean(Xv[ok] / np.linalg.norm(Xv[ok], axis=1, keepdims=True), axis=0)
    right /= np.linalg.norm(right)
    down = down - (down @ right) * right
    down /= np.linalg.norm(down)
    return right, down, np.cross(right, down)


def measuring_frame(canopy: np.ndarray, background: np.ndarray, ground, right, down, view,
                    scale: float, seed: int = 0) -> MeasuringFrame:
    """The frame for canopy extents.

    Args:
        canopy, background: (N, 3) plant points and other points (ground candidates).
        ground: ``"auto"`` (fit a ground plane, else image up), ``"camera"``
            (image up), ``"view"`` (up = towards the camera: top views) or a
            plane ``(a, b, c, d)``, ``a x + b y + c z + d = 0``, whose normal
            side holding most of the canopy is up.
        right, down, view: world directions of the image axes and the view.
        scale: typical distance to the scene (sets the RANSAC threshold, 1 %).
    """
    centre = canopy.mean(axis=0)
    if isinstance(ground, str):
        if ground in ("camera", "none"):
            return MeasuringFrame(centre, frame_from_up(-down, right, centre), "camera")
        if ground == "view":
            return MeasuringFrame(centre, frame_from_up(-view, right, centre), "view")
        if ground != "auto":
            raise CanopyStereoError(
                f"ground must be 'auto', 'camera', 'view' or a plane a,b,c,d; got {ground!r}")
        found = find_ground(background, canopy, -down, threshold=0.01 * scale, seed=seed)
        if found is None:
            return MeasuringFrame(centre, frame_from_up(-down, right, centre), "camera")
        n, d, count = found
        kind = "ground"
    else:
        try:
            plane = np.asarray(ground, np.float64).ravel()
        except (TypeError, ValueError):
            raise CanopyStereoError(f"ground plane must be 4 numbers a,b,c,d; got {ground!r}") from None
        if plane.size != 4 or not np.all(np.isfinite(plane)) or np.linalg.norm(plane[:3]) == 0:
            raise CanopyStereoError(f"ground plane must be 4 finite numbers a,b,c,d with (a,b,c) != 0; "
                                    f"got {ground!r}")
        norm = np.linalg.norm(plane[:3])
        n, d = plane[:3] / norm, plane[3] / norm
        if np.median(canopy @ n + d) < 0:
            n, d = -n, -d
        count, kind = 0, "plane"
    foot = centre - (centre @ n + d) * n
    return MeasuringFrame(foot, frame_from_up(n, right, foot), kind,
                          ground_plane=np.append(n, d), ground_inliers=count)


def _local_median(values: np.ndarray, sample: np.ndarray, at: np.ndarray, window: int,
                  step: int = 3) -> np.ndarray:
    """(H, W) median of ``values`` over the ``sample`` pixels in a ``window`` square
    around each pixel of ``at`` (every ``step``-th offset); NaN elsewhere or when
    there is no sample."""
    r = window // 2
    h, w = values.shape
    vals = np.where(sample, values, np.nan)
    pad = np.pad(vals, r, constant_values=np.nan)
    vs, us = np.nonzero(at)
    offs = range(0, 2 * r + 1, step)
    stack = np.stack([pad[vs + dv, us + du] for dv in offs for du in offs], axis=1)
    out = np.full((h, w), np.nan)
    with np.errstate(all="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out[vs, us] = np.nanmedian(stack, axis=1)
    return out


def _clean_canopy(organized, plant, background=None, viewpoint=None, jump_factor: float = 8.0,
                  min_part: int = 10, window: int = 31, all_plant=None):
    """Plant pixels without matching debris.

    Drops pieces cut off from the rest by depth jumps when smaller than
    ``min_part`` pixels, and,
    with a ``viewpoint`` (camera centre) and a ``background`` mask, points whose
    distance is nearer the median distance of the background pixels than that
    of the plant pixels (``all_plant``, default ``plant``) in a ``window``-pixel
    square around them (background depths bled onto the plant's rim; where the
    plant touches its ground both are alike and the points stay).
    """
    keep = plant.copy()
    if viewpoint is not None and background is not None and background.any():
        dist = np.linalg.norm(organized - np.asarray(viewpoint, np.float64), axis=-1)
        finite = np.isfinite(dist)
        local_bg = _local_median(dist, background & finite, plant, window)
        # the plant's own distance around a pixel: all plant pixels with a point
        local_plant = _local_median(dist, all_plant if all_plant is not None else plant, plant, window)
        with np.errstate(invalid="ignore"):
            debris = np.isfinite(local_bg) & (np.abs(dist - local_bg) < np.abs(dist - local_plant))
        keep &= ~debris
    spacing = neighbour_spacing(organized, keep)
    if np.isfinite(spacing) and spacing > 0:
        labels = connected_surface_parts(organized, keep, jump_factor * spacing)
        counts = np.bincount(labels.ravel())
        counts[0] = 0
        big = np.nonzero(counts >= min_part)[0]
        keep = np.isin(labels, big)
    return keep if keep.sum() >= 3 else plant


def median_along_rays(organized: np.ndarray, keep: np.ndarray, viewpoint, radius: int = 3) -> np.ndarray:
    """Points of ``keep`` (N, 3) with their distance from ``viewpoint`` replaced
    by the median over their ``(2 radius + 1)^2`` neighbours in ``keep``.

    Each point stays on its own line of sight, where a reconstruction errs, so
    this removes matching noise (which would widen the extents) without
    moving points across the image.
    """
    C = np.asarray(viewpoint, np.float64).reshape(3)
    rel = np.where(keep[..., None], organized - C, np.nan)
    dist = np.linalg.norm(rel, axis=-1)
    h, w = dist.shape
    pad = np.pad(dist, radius, constant_values=np.nan)
    vs, us = np.nonzero(keep)
    windows = np.stack([pad[vs + dv, us + du] for dv in range(2 * radius + 1)
                        for du in range(2 * radius + 1)], axis=1)
    med = np.nanmedian(windows, axis=1)
    return C + rel[vs, us] * (med / dist[vs, us])[:, None]


def drop_isolated_points(points: np.ndarray, k: int = 8, factor: float = 4.0) -> np.ndarray:
    """Points whose mean distance to their ``k`` nearest neighbours is at most
    ``factor`` times the median of that distance (statistical outlier removal)."""
    from scipy.spatial import cKDTree

    P = np.asarray(points, np.float64)
    if len(P) <= 2 * k:
        return P
    d, _ = cKDTree(P).query(P, k=k + 1)
    mean_d = d[:, 1:].mean(axis=1)
    return P[mean_d <= factor * np.median(mean_d)]


def drop_detached_clusters(points: np.ndarray, cell: float, min_fraction: float = 0.002,
                           candidates: np.ndarray | None = None) -> np.ndarray:
    """Keep-mask (N,) of points not in small clusters detached from the rest.

    Points are binned into cubic cells of edge ``cell``; occupied cells touching
    (26-neighbourhood) form clusters. Clusters holding fewer than
    ``min_fraction`` of the points are dropped: stray matches floating off the
    canopy (a mismatched sliver of a leaf seen edge-on lands tens of
    centimetres behind it), which would set the extents. With ``candidates``
    (N,) bool, only those points may be dropped.
    """
    from scipy import ndimage

    P = np.asarray(points, np.float64)
    keep = np.ones(len(P), bool)
    if len(P) < 10 or not (cell > 0):
        return keep
    idx = np.floor((P - P.min(axis=0)) / cell).astype(np.int64)
    shape = idx.max(axis=0) + 1
    if np.prod(shape) > 50_000_000:  # absurd spread for the cell: leave the points alone
        return keep
    grid = np.zeros(shape, bool)
    grid[idx[:, 0], idx[:, 1], idx[:, 2]] = True
    labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return keep
    point_label = labels[idx[:, 0], idx[:, 1], idx[:, 2]]
    counts = np.bincount(point_label, minlength=n + 1)
    small = counts[point_label] < min_fraction * len(P)
    if candidates is not None:
        small &= candidates
    return ~small


def measure_scene(organized, leaf_ids=None, mask=None, ground="auto", unit: str = "mm",
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
    exact_cloud = bool(all_plant.sum() >= 16 and roughness(organized, all_plant) < EXACT_ROUGHNESS)
    leaves, skipped, leaf_surfaces = [], [], []
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
            kept = _clean_canopy(organized, plant_valid, background_mask, viewpoint, all_plant=all_plant)
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
    right, down, view = _image_directions(organized, finite, P)
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


def measure_organized(organized, leaf_ids=None, mask=None, ground="auto", unit: str = "mm",
                      camera="auto", voxel_size: float | None = None, **options) -> dict:
    """The REPORT.json dict of an organized cloud (see :func:`measure_scene`)."""
    return measure_scene(organized, leaf_ids=leaf_ids, mask=mask, ground=ground, unit=unit,
                         camera=camera, voxel_size=voxel_size, **options).report


def measure_points(points, ground="auto", unit: str = "mm", voxel_size: float | None = None,
                   up=(0.0, -1.0, 0.0), right=(1.0, 0.0, 0.0)) -> SceneMeasurement:
    """Canopy size of an unorganized cloud (e.g. a PLY file); no per-leaf sizes.

    Without a pixel grid there is no image direction: ``up`` and ``right``
    give the world's up and right (default: the rigs' convention, world +Y
    roughly image-down, +X right). With ``ground="auto"`` a ground plane
    within 35 degrees of ``up`` is searched among all points and the points
    on it are not canopy.
    """
    P = np.asarray(points, np.float64).reshape(-1, 3)
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


def load_cloud(path):
    """Read a cloud to measure: ``.npy`` organized (H, W, 3) or ``.ply`` points.

    Returns ``(array, unit)``; ``unit`` is the PLY's ``comment unit`` or None.
    Raises :class:`CanopyStereoError` for missing, unreadable or wrong files.
    """
    path = Path(path)
    if not path.is_file():
        raise CanopyStereoError(f"cloud file not found: {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise CanopyStereoError(f"{path} is not a readable .npy array: {exc}") from None
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise CanopyStereoError(
                f"{path} must hold an organized cloud of shape (H, W, 3), got {arr.shape}")
        if arr.dtype.kind not in "fiu":
            raise CanopyStereoError(f"{path} must hold real coordinates (float), got dtype {arr.dtype}")
        return check_organized(arr), None
    if suffix == ".ply":
        cloud = read_ply(path)
        return cloud.points, cloud.unit
    raise CanopyStereoError(f"{path}: unsupported cloud file (expected ORG.npy from "
                            "'reconstruct --organized' or a .ply point cloud)")


def _to_builtin(obj):
    if isinstance(obj, dict):
        return {k: _to_builtin(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_builtin(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _to_builtin(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating,)):
        obj = float(obj)
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_report(report: dict, path, csv=None) -> Path:
    """Write ``report`` as JSON to ``path`` (and the leaves as CSV to ``csv``).

    Non-finite numbers are written as ``null``. Returns the JSON path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_to_builtin(report), indent=2) + "\n", encoding="utf-8")
    if csv is not None:
        write_leaves_csv(report, csv)
    return path


def write_leaves_csv(report: dict, path) -> Path:
    """One row per measured leaf (:data:`CSV_COLUMNS`), lengths in the report's unit."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = _csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for lf in report.get("leaves", []):
            n, c = lf["normal"], lf["centroid"]
            w.writerow([lf["id"], f"{lf['length']:.3f}", f"{lf['width']:.3f}", f"{lf['area']:.3f}",
                        f"{lf['chord']:.3f}", f"{n[0]:.5f}", f"{n[1]:.5f}", f"{n[2]:.5f}",
                        f"{c[0]:.3f}", f"{c[1]:.3f}", f"{c[2]:.3f}", f"{lf['plane_rms']:.4f}",
                        lf["n_pixels"], lf["n_points"], int(lf["complete"]), int(lf["touches_border"]),
                        "" if lf.get("view_angle_deg") is None else f"{lf['view_angle_deg']:.1f}",
                        int(bool(lf.get("reliable", False))), lf.get("surface_model", "")])
    return path
