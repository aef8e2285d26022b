"""The one measuring pipeline: a stereo frame (left image + rectified disparity) -> the plant's traits.

Every entry point that measures calls :func:`measure_plant` with the same defaults
(``canopy-stereo reconstruct --measure``, ``batch``, ``demo``, ``view``, ``paper`` and the
measuring nodes), so the same stereo pair and options give the same numbers everywhere:

1. the cloud: the rectified disparity mapped back to the original left pixels and
   triangulated with the rig's world-frame ``P`` (:func:`original_cloud_mm`, exactly the
   cloud of :func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`), millimetres;
2. the plant mask on the original left image (:func:`plant_mask_of`, the one place the
   automatic segmentation is called): a given mask, the automatic plant mask (default),
   or the whole scene;
3. the measurement (:func:`~canopy_stereo.measure.measure_scene`: leaves separated and
   measured, canopy cleaned, ground reference ``ground``, voxel edge ``voxel_size_mm``,
   the left camera given);
4. the report in the package's one unit set (:func:`~canopy_stereo.measure.lab_report`):
   lengths mm, areas cm^2, volumes cm^3.

Inputs are what every entry point has: the raw left image and the rectified disparity
(``reconstruct_pair``'s ``rec.disparity``; the graph's ``disparity`` with the
``left/image_raw`` of the same stamp); :func:`canopy_stereo.pipeline.plant.measure_stereo_pair`
does both steps for a raw pair.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.rectification import Rectification

#: Voxel edge of the occupancy volume (mm): one fixed size, so volumes compare across a season.
DEFAULT_VOXEL_SIZE_MM = 10.0
#: Ground reference of the canopy heights (see :func:`~canopy_stereo.measure.frame.measuring_frame`).
DEFAULT_GROUND = "auto"
#: Colour cue of the automatic plant mask (with the depth cue; see :func:`plant_mask_of`).
DEFAULT_COLOUR_INDEX = "exg"
#: What the mask of a measurement was: given by the user, found automatically, none (whole scene).
MASK_SOURCES = ("given", "automatic", "whole scene")


@dataclass
class PlantMeasurement:
    """What :func:`measure_plant` measured.

    Attributes:
        report: the REPORT.json dict in the one unit set (lengths mm, areas cm^2, volumes
            cm^3; ``report["units"]`` says so), with ``report["source"]["mask"]`` and
            ``report["canopy"]["voxel_size"]`` (mm) recording how it was measured.
        scene: the :class:`~canopy_stereo.measure.SceneMeasurement` (millimetres, original
            left grid) the report came from, for :func:`~canopy_stereo.measure.plot_views`.
        mask: (H, W) bool plant mask on the original left image (all valid points for the
            whole scene).
        mask_source: one of :data:`MASK_SOURCES`.
        organized_mm: (H, W, 3) float64 world points (mm) of the original left pixels, NaN = none
            (as :func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair` maps them).
        instances: (H, W) int plant numbers 1..N, left to right (automatic mask), else None.

    ``report["plants"]``: one entry per plant (``plant_index`` 1..N left to right for the
    automatic mask, 0 for a given mask or the whole scene): its ``reference`` surface (pot
    rim, soil, ground; None for a lone plant measured as the scene), ``canopy`` (height above
    that reference), ``n_leaves``, ``leaf_area`` (cm^2), ``mean_leaf_length``/``width`` (mm),
    ``error`` (None; for a plant that could not be measured the one-line reason, and its figures
    None: :func:`plant_summary`). ``report["n_plants"]`` counts the entries,
    ``report["n_plants_not_measured"]`` those with an ``error``. With several plants each is
    measured on its own as well as all together (the top-level ``canopy`` and ``leaves``).
    """

    report: dict
    scene: object
    mask: np.ndarray
    mask_source: str
    organized_mm: np.ndarray
    instances: np.ndarray | None = None


def original_cloud_mm(disparity, rig, rectification: Rectification) -> np.ndarray:
    """(H, W, 3) float64 world points in millimetres of the ORIGINAL left pixels from a
    rectified disparity (pixels ``u_left - u_right``, negative or NaN = none), NaN where
    none: :func:`~canopy_stereo.geometry.triangulation.organized_from_disparity`, as
    ``reconstruct_pair`` maps it."""
    from canopy_stereo.geometry.triangulation import organized_from_disparity

    disp = np.asarray(disparity, np.float32)
    doffs = np.float32(rectification.doffs)
    if doffs != 0:
        # the values as the graph carries them (disparity_node publishes d - doffs in float32 and
        # the measuring side adds doffs back): float32 rounding then gives every entry point the
        # same disparity to the last bit (a no-op on values that made that round trip already)
        disp = (disp - doffs) + doffs
    disp = np.where(np.isfinite(disp), disp, np.float32(-1))
    org = organized_from_disparity(disp, rectification, rig.P_left, rig.P_right, rig.image_size,
                                   D_left=rig.D_left)
    return org * (rig.metres_per_unit * 1000.0)


def mask_on_original(mask_rect, disparity, rig, rectification: Rectification) -> np.ndarray:
    """(H, W) bool: the original left pixels whose rectified match (the disparity sampled as
    :func:`original_cloud_mm` samples it) lies on ``mask_rect`` ((Hr, Wr), non-zero = on):
    a mask drawn on the rectified image (e.g. a recorded ``left/mask``) carried to the
    original grid the measurement works on."""
    disp = np.asarray(disparity, np.float32)
    masked = np.where(np.asarray(mask_rect) > 0, disp, np.float32(-1))
    return np.all(np.isfinite(original_cloud_mm(masked, rig, rectification)), axis=-1)


def to_rectified_grid(image, rig, rectification: Rectification) -> np.ndarray:
    """A label image drawn on the original left image (mask, leaf ids) carried to the
    rectified left grid (to draw it over the rectified image), nearest neighbour
    (undistortion included); 0 outside."""
    import cv2

    from canopy_stereo.geometry.rectification import cached_rectifier

    arr = np.asarray(image)
    if arr.ndim == 3:
        arr = arr.max(axis=2)
    if arr.shape[::-1] != tuple(rig.image_size):
        raise CanopyStereoError(f"mask/leaf-id image is {arr.shape[1]}x{arr.shape[0]} but the rig's "
                                f"images are {rig.image_size[0]}x{rig.image_size[1]}")
    rectifier = cached_rectifier(rig, rectification, interpolation=cv2.INTER_NEAREST)
    if arr.dtype == np.bool_ or arr.dtype == np.uint8:
        return rectifier.rectify_one(arr.astype(np.uint8), "left")
    # any integer label (ids up to 2^24 are exact in float32): remap has no int32 maps
    return np.rint(rectifier.rectify_one(arr.astype(np.float32), "left")).astype(np.int64)


def plant_mask_of(left_bgr, organized_mm, *, camera_mm, index: str = DEFAULT_COLOUR_INDEX):
    """The automatic plant segmentation of the original left image and its cloud (mm, same
    grid; ``camera_mm`` (3, 4) the left camera's ``P`` of millimetres): the one place the
    measuring pipeline calls it (:func:`~canopy_stereo.segmentation.segment_plants`: colour,
    texture, depth and 3D shape; plants numbered left to right). Returns its
    ``PlantSegmentation`` (``.mask`` uint8 255 = plant, ``.instances``). ``index`` is not
    used by it (kept for the colour-index seeder's callers)."""
    from canopy_stereo.segmentation import segment_plants

    del index
    if int(np.all(np.isfinite(organized_mm), axis=-1).sum()) < 3:
        raise CanopyStereoError("no 3D point to find the plant by (the disparity is empty)")
    return segment_plants(left_bgr, points=organized_mm, camera=camera_mm)


def camera_mm_of(rig) -> np.ndarray:
    """(3, 4) the rig's left ``P`` taking world points in millimetres."""
    k = 1e-3 / rig.metres_per_unit
    return np.asarray(rig.P_left, np.float64) @ np.diag([k, k, k, 1.0])


def automatic_plant_mask(left_bgr, organized, rig, *, index: str = DEFAULT_COLOUR_INDEX) -> np.ndarray:
    """(H, W) bool: the plants :func:`plant_mask_of` finds in the original left image and its
    organized cloud in the rig's world units (``Reconstruction.organized``), as
    :func:`measure_plant` finds them."""
    mm = rig.metres_per_unit * 1000.0
    seg = plant_mask_of(left_bgr, np.asarray(organized, np.float64) * mm, camera_mm=camera_mm_of(rig), index=index)
    return np.asarray(seg.mask) > 0


def measure_plant(left_bgr, disparity, rig, *, rectification: Rectification, mask=None,
                  leaf_ids=None, whole_scene: bool = False, index: str = DEFAULT_COLOUR_INDEX,
                  ground=DEFAULT_GROUND, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> PlantMeasurement:
    """Measure the plant of one stereo frame (the package's one measuring pipeline).

    The rectified disparity is mapped to the original left pixels
    (:func:`original_cloud_mm`, the cloud ``reconstruct_pair`` makes), the plant is found
    there (:func:`plant_mask_of`) and measured with the left camera ``P`` given.

    Args:
        left_bgr: (H, W, 3) uint8 ORIGINAL (raw) left image, BGR, the rig's size (None only
            with ``mask`` or ``whole_scene``).
        disparity: (Hr, Wr) rectified left disparity, pixels; negative or NaN = none.
        rig: :class:`~canopy_stereo.io.rig.Rig` (any world unit).
        rectification: the :class:`Rectification` of the disparity.
        mask: optional (H, W) plant mask on the original left image (non-zero = plant);
            default: the automatic plant mask.
        leaf_ids: optional (H, W) leaf-id image on the original left image (0 = none).
        whole_scene: measure every point (no plant mask, the old behaviour).
        index: colour cue of the automatic mask.
        ground: ground reference of the heights (``"auto"``, ``"none"``, ...).
        voxel_size_mm: voxel edge of the occupancy volume, millimetres (> 0).

    Returns a :class:`PlantMeasurement`; raises :class:`CanopyStereoError` with one line
    when there is nothing to measure.
    """
    from canopy_stereo.measure.scene import measure_scene
    from canopy_stereo.measure.units import lab_report

    if not (np.isfinite(voxel_size_mm) and voxel_size_mm > 0):
        raise CanopyStereoError(f"voxel size must be > 0 mm, got {voxel_size_mm}")
    if whole_scene and mask is not None:
        raise CanopyStereoError("a mask and the whole scene exclude each other")
    organized = original_cloud_mm(disparity, rig, rectification)
    finite = np.all(np.isfinite(organized), axis=-1)
    if left_bgr is None and mask is None and not whole_scene:
        raise CanopyStereoError("finding the plant needs the left image (or give a mask, or the whole scene)")
    if left_bgr is not None and np.asarray(left_bgr).shape[:2] != organized.shape[:2]:
        raise CanopyStereoError(f"the left image is {np.asarray(left_bgr).shape[1]}x{np.asarray(left_bgr).shape[0]} "
                                f"but the rig's images are {organized.shape[1]}x{organized.shape[0]}")
    camera_mm = camera_mm_of(rig)
    instances = None
    if whole_scene:
        plant, source = finite, "whole scene"
    elif mask is not None:
        plant = np.asarray(mask)
        plant, source = (plant.max(axis=2) if plant.ndim == 3 else plant) > 0, "given"
    else:
        seg = plant_mask_of(left_bgr, organized, camera_mm=camera_mm, index=index)
        plant, instances, source = np.asarray(seg.mask) > 0, np.asarray(seg.instances), "automatic"
        if not plant.any():
            raise CanopyStereoError("no plant found in the image (the automatic plant mask is empty); "
                                    "give a mask, or measure the whole scene")
    n_plants = 0 if instances is None else int(instances.max())
    if n_plants == 1:  # a lone plant as measure_plants measures each: without the background behind it
        from canopy_stereo.measure.plants import trimmed_mask

        plant = trimmed_mask(organized, plant, camera=camera_mm)
    plants: list[dict] = []
    if n_plants > 1:  # each plant on its own: height from its pot rim / soil / the ground
        from canopy_stereo.measure.plants import measure_plants

        per = measure_plants(organized, instances, ground=ground, unit="mm", camera=camera_mm,
                             voxel_size=voxel_size_mm)
        plants = [lab_report(p) for p in per["plants"]]
    scene = measure_scene(organized, leaf_ids=leaf_ids, mask=None if whole_scene else plant, ground=ground,
                          unit="mm", camera=camera_mm, voxel_size=voxel_size_mm)
    if n_plants == 1:  # one plant: its height from its pot rim / soil (measure_plants' reference)
        scene.report["reference"] = _reference_of(scene, organized, plant, camera_mm)
    report = lab_report(scene.report)
    report["source"]["mask"] = source
    if not plants:  # one plant (or the mask/scene as one): the whole report is that plant's
        plants = [{"plant_index": 1 if n_plants else 0, **report}]
    report["plants"] = [plant_summary(p) for p in plants]
    report["n_plants"] = len(report["plants"])
    report["n_plants_not_measured"] = sum(p["error"] is not None for p in report["plants"])
    return PlantMeasurement(report=report, scene=scene, mask=plant, mask_source=source, organized_mm=organized,
                            instances=instances)


def _reference_of(scene, organized, plant, camera_mm) -> dict:
    """The reference surface of a lone plant (:func:`~canopy_stereo.measure.plants.reference_surface`)
    and its canopy height made the top above it, as :func:`~canopy_stereo.measure.plants.measure_plants`
    reports each plant (``extent_height``: the plant's own extent)."""
    from canopy_stereo.geometry.camera import camera_centre
    from canopy_stereo.measure.plants import reference_surface

    scale = float(np.median(np.linalg.norm(scene.canopy_points - camera_centre(camera_mm), axis=1)))
    ref = reference_surface(organized, plant, np.zeros_like(plant), scene.frame, scene.canopy_points, scale=scale)
    canopy = scene.report["canopy"]
    canopy["extent_height"] = canopy["height"]
    canopy["height"] = ref["plant_height"]
    return ref


def plant_summary(p: dict) -> dict:
    """One plant's entry of ``report["plants"]`` from its report (lab units): its index,
    ``error`` (None), reference surface, canopy, leaf count, leaf area (cm^2), mean leaf length
    and width (mm).

    A plant that could not be measured (``p["error"]``: the one-line reason, as
    :func:`~canopy_stereo.measure.plants.measure_plants` gives it) keeps its index, its
    ``at_image_border`` and that ``error``; its ``reference``, ``canopy``, ``n_leaves``,
    ``leaf_area`` and mean leaf sizes are None (not measured: REPORT.json's ``null``)."""
    index, border = int(p.get("plant_index", 0)), p.get("at_image_border")
    if p.get("error") is not None:
        return {"plant_index": index, "error": str(p["error"]), "at_image_border": border,
                **dict.fromkeys(("reference", "canopy", "n_leaves", "leaf_area", "mean_leaf_length",
                                 "mean_leaf_width"))}
    return {"plant_index": index, "error": None, "reference": p.get("reference"), "at_image_border": border,
            "canopy": p["canopy"], "n_leaves": len(p.get("leaves", [])),
            "leaf_area": float(sum(lf["area"] for lf in p.get("leaves", []))),
            "mean_leaf_length": float(np.mean([lf["length"] for lf in p["leaves"]])) if p.get("leaves") else None,
            "mean_leaf_width": float(np.mean([lf["width"] for lf in p["leaves"]])) if p.get("leaves") else None}


#: What each mask source means, for the summaries.
_MASK_WORDS = {"given": "the given mask", "automatic": "the automatic plant mask",
               "whole scene": "every point (whole scene, no plant mask)"}


def measurement_lines(report: dict, *, max_leaves: int = 8) -> list[str]:
    """Summary lines of a :func:`measure_plant` report, in the one unit set (mm, cm^2, cm^3):
    what was measured, the canopy, each plant when there are several (one that could not be
    measured: ``plant K: not measured: <reason>``), the leaves (the first ``max_leaves``)."""
    c = report["canopy"]
    plants = report.get("plants", [])
    failed = sum(p.get("error") is not None for p in plants)
    ref = report.get("reference") or {}
    reference = ref.get("kind") or report.get("frame", {}).get("kind", "?")
    what = _MASK_WORDS.get(report["source"].get("mask"), report["source"].get("mask"))
    counted = f"{len(plants)} plants" + (f", {failed} not measured" if failed else "")
    lines = [f"measured: {what}" + (f" ({counted})" if len(plants) > 1 or failed else "")
             + f"; reference: {reference}; voxels {c['voxel_size']:g} mm",
             f"canopy: height {c['height']:.0f} mm, width {c['width']:.0f} mm, depth {c['depth']:.0f} mm"
             + (f", top {c['top_above_ground']:.0f} mm above the ground"
                if c.get("top_above_ground") is not None else ""),
             f"  volumes: convex hull {c['hull_volume']:.0f} cm^3, voxels {c['voxel_volume']:.0f} cm^3; "
             f"leaves measured: {c.get('n_leaves', 0)}"
             + (f", leaf area {c['leaf_area']:.0f} cm^2" if c.get("leaf_area") else "")]
    if len(plants) > 1 or failed:
        for p in plants:
            if p.get("error") is not None:
                lines.append(f"  plant {p['plant_index']}: not measured: {p['error']}")
                continue
            pc, pref = p["canopy"], (p.get("reference") or {}).get("kind", "?")
            lines.append(f"  plant {p['plant_index']}: height {pc['height']:.0f} mm above its {pref}, "
                         f"width {pc['width']:.0f} mm, hull {pc['hull_volume']:.0f} cm^3, leaves {p['n_leaves']}")
    leaves = report.get("leaves", [])
    for leaf in leaves[:max_leaves]:
        # no width: no single midrib was found (a cluster of leaves), not a leaf 0 mm wide
        width = f"width {leaf['width']:.0f} mm" if leaf["width"] > 0 else "width not measured (no single midrib)"
        lines.append(f"  leaf {leaf['id']}: length {leaf['length']:.0f} mm, {width}, area {leaf['area']:.1f} cm^2")
    if len(leaves) > max_leaves:
        lines.append(f"  ... {len(leaves) - max_leaves} more leaves")
    return lines


def write_overlay(path, measured: PlantMeasurement, left_bgr):
    """Write the mask overlay picture (:func:`~canopy_stereo.segmentation.mask_overlay`: the
    mask's outline and the plants' numbers over the original left image) of a measurement;
    returns the path."""
    from canopy_stereo.io.images import write_image
    from canopy_stereo.segmentation import mask_overlay

    mask = np.asarray(measured.mask, bool).astype(np.uint8) * 255
    return write_image(path, mask_overlay(left_bgr, mask, instances=measured.instances))
