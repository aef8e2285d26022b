"""The package's one unit set for measurements: lengths mm, areas cm^2, volumes cm^3.

Every output a user reads (command summaries, REPORT.json, CSV tables, plots, viewer
labels) states measurements in these units, whatever the rig's world unit;
:func:`lab_report` converts a report of :func:`~canopy_stereo.measure.measure_scene`
(lengths in its ``unit``) to them. Leaf-area density is leaf area / hull volume in
cm^2 / cm^3 = 1/cm. CSV column names carry the unit (``length_mm``, ``area_cm2``, ...).
"""
from __future__ import annotations

from canopy_stereo.errors import CanopyStereoError

#: Unit of each kind of quantity in every output of the package.
LAB_UNITS = {"length": "mm", "area": "cm^2", "volume": "cm^3", "leaf_area_density": "1/cm"}
#: Millimetres per world unit of the units a report may be in.
MM_PER_UNIT = {"mm": 1.0, "cm": 10.0, "dm": 100.0, "m": 1000.0, "in": 25.4, "ft": 304.8}

_LEAF_LENGTHS = ("length", "width", "chord", "plane_rms", "geodesic_length")
_LEAF_POINTS = ("centroid",)
_LEAF_POINT_LISTS = ("ends", "width_ends")
_CANOPY_LENGTHS = ("height", "width", "depth", "top_above_ground", "base_above_ground", "voxel_size",
                   "extent_height")
_CANOPY_POINTS = ("bbox_min", "bbox_max", "centroid")


def mm_per_unit(unit: str) -> float:
    """Millimetres in one ``unit`` (:data:`MM_PER_UNIT`), or :class:`CanopyStereoError`."""
    try:
        return MM_PER_UNIT[str(unit)]
    except KeyError:
        raise CanopyStereoError(f"unknown length unit {unit!r}; expected one of {', '.join(MM_PER_UNIT)}") from None


def _scaled(v, k):
    if v is None:
        return None
    if isinstance(v, (list, tuple)):
        return [_scaled(x, k) for x in v]
    return float(v) * k


def lab_report(report: dict) -> dict:
    """A copy of a REPORT.json dict in :data:`LAB_UNITS` (lengths mm, areas cm^2, volumes
    cm^3, leaf-area density 1/cm). A report already in them is returned as a copy unchanged."""
    import copy

    out = copy.deepcopy(report)
    if out.get("units") == LAB_UNITS:
        return out
    mm = mm_per_unit(out.get("unit", "mm"))
    cm2, cm3 = mm * mm / 100.0, mm ** 3 / 1000.0
    for lf in out.get("leaves", []):
        for key in _LEAF_LENGTHS + _LEAF_POINTS + _LEAF_POINT_LISTS:
            if key in lf:
                lf[key] = _scaled(lf[key], mm)
        if "area" in lf:
            lf["area"] = _scaled(lf["area"], cm2)
    c = out.get("canopy", {})
    for key in _CANOPY_LENGTHS + _CANOPY_POINTS:
        if key in c:
            c[key] = _scaled(c[key], mm)
    for key in ("hull_volume", "voxel_volume"):
        if key in c:
            c[key] = _scaled(c[key], cm3)
    if "leaf_area" in c:
        c["leaf_area"] = _scaled(c["leaf_area"], cm2)
    if c.get("leaf_area") is not None and c.get("hull_volume"):
        c["leaf_area_density"] = c["leaf_area"] / c["hull_volume"]
    elif "leaf_area_density" in c:
        c["leaf_area_density"] = None
    ref = out.get("reference")
    if isinstance(ref, dict):
        for key in ("height", "height_above_ground"):
            if ref.get(key) is not None:
                ref[key] = float(ref[key]) * mm
    src = out.get("source")
    if isinstance(src, dict) and src.get("camera_centre") is not None:
        src["camera_centre"] = _scaled(src["camera_centre"], mm)
    f = out.get("frame")
    if isinstance(f, dict):
        if f.get("origin") is not None:
            f["origin"] = _scaled(f["origin"], mm)
        if f.get("ground_plane") is not None:  # n . x + d = 0: d is a length
            f["ground_plane"] = list(f["ground_plane"][:3]) + [float(f["ground_plane"][3]) * mm]
    out["unit"] = "mm"
    out["units"] = dict(LAB_UNITS)
    return out
