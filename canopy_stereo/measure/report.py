"""The measurement report: REPORT.json and the per-leaf CSV written, clouds to measure read.

REPORT.json layout as written (:func:`write_report`: the package's one unit set,
:mod:`canopy_stereo.measure.units`: lengths and coordinates in mm, areas in cm^2, volumes
in cm^3, leaf-area density in 1/cm, whatever the rig's unit; the dict
:func:`~canopy_stereo.measure.measure_scene` returns is in its cloud's ``unit``)::

    {"unit": "mm",
     "units": {"length": "mm", "area": "cm^2", "volume": "cm^3", "leaf_area_density": "1/cm"},
     "source": {...},                    # image size, points, camera, leaf ids / mask used
     "frame": {...},                     # measuring frame (see frame.MeasuringFrame)
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
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.ply import read_ply
from canopy_stereo.measure.scene import check_organized
from canopy_stereo.measure.units import lab_report

#: Columns of the per-leaf CSV (units in the names; the others are counts, flags, a unit vector).
CSV_COLUMNS = ["id", "length_mm", "width_mm", "area_cm2", "chord_mm", "normal_x", "normal_y", "normal_z",
               "centroid_x_mm", "centroid_y_mm", "centroid_z_mm", "plane_rms_mm", "n_pixels", "n_points",
               "complete", "touches_border", "view_angle_deg", "reliable", "surface_model"]


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
        return check_organized(arr, name=f"{path} (an organized cloud)"), None
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


def write_report(report: dict, path, *, csv=None) -> Path:
    """Write ``report`` as JSON to ``path`` (and the leaves as CSV to ``csv``), in the
    package's one unit set (:func:`~canopy_stereo.measure.units.lab_report`).

    Non-finite numbers are written as ``null``. Returns the JSON path.
    """
    report = lab_report(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(_to_builtin(report), indent=2) + "\n", encoding="utf-8")
    if csv is not None:
        write_leaves_csv(report, csv)
    return path


def write_leaves_csv(report: dict, path) -> Path:
    """One row per measured leaf (:data:`CSV_COLUMNS`: lengths mm, areas cm^2)."""
    report = lab_report(report)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = _csv.writer(f)
        w.writerow(CSV_COLUMNS)
        for lf in report.get("leaves", []):
            n, c = lf["normal"], lf["centroid"]
            w.writerow([lf["id"], f"{lf['length']:.3f}", f"{lf['width']:.3f}", f"{lf['area']:.4f}",
                        f"{lf['chord']:.3f}", f"{n[0]:.5f}", f"{n[1]:.5f}", f"{n[2]:.5f}",
                        f"{c[0]:.3f}", f"{c[1]:.3f}", f"{c[2]:.3f}", f"{lf['plane_rms']:.4f}",
                        lf["n_pixels"], lf["n_points"], int(lf["complete"]), int(lf["touches_border"]),
                        "" if lf.get("view_angle_deg") is None else f"{lf['view_angle_deg']:.1f}",
                        int(bool(lf.get("reliable", False))), lf.get("surface_model", "")])
    return path
