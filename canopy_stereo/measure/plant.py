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
    """

    report: dict
    scene: object
    mask: np.ndarray
    mask_source: str
    organized_mm: np.ndarray


def original_cloud_mm(disparity, rig, rectification: Rectification) -> np.ndarray:
    """(H, W, 3) float64 world points in millimetres of the ORIGINAL left pixels from a
    rectified disparity (pixels ``u_left - u_right``, negative or NaN = none), NaN where
    none: :func:`~canopy_stereo.geometry.triangulation.organized_from_disparity`, as
    ``reconstruct_pair`` maps it."""
    from canopy_stereo.geometry.triangulation import organized_from_disparity

    disp = np.asarray(disparity, np.float32)
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


def plant_mask_of(left_bgr, organized_mm, *, camera_centre_mm, index: str = DEFAULT_COLOUR_INDEX) -> np.ndarray:
    """The automatic plant mask (bool (H, W)) of the original left image and its cloud
    (mm, same grid; ``camera_centre_mm`` (3,) the left camera's centre, mm): the one place
    the measuring pipeline calls the automatic segmentation (colour cue ``index`` with the
    distance from the camera as the depth cue)."""
    from canopy_stereo.segmentation import auto_plant_mask

    if int(np.all(np.isfinite(organized_mm), axis=-1).sum()) < 3:
        raise CanopyStereoError("no 3D point to find the plant by (the disparity is empty)")
    distance = np.linalg.norm(organized_mm - np.asarray(camera_centre_mm, np.float64), axis=-1)
    return auto_plant_mask(left_bgr, depth=distance, index=index) > 0


def automatic_plant_mask(left_bgr, organized, rig, *, index: str = DEFAULT_COLOUR_INDEX) -> np.ndarray:
    """:func:`plant_mask_of` of the original left image and its organized cloud in the rig's
    world units (``Reconstruction.organized``), as :func:`measure_plant` finds the plant."""
    from canopy_stereo.geometry.camera import camera_centre

    mm = rig.metres_per_unit * 1000.0
    return plant_mask_of(left_bgr, np.asarray(organized, np.float64) * mm,
                         camera_centre_mm=camera_centre(rig.P_left) * mm, index=index)


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
    from canopy_stereo.geometry.camera import camera_centre
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
    if whole_scene:
        plant, source = finite, "whole scene"
    elif mask is not None:
        plant = np.asarray(mask)
        plant, source = (plant.max(axis=2) if plant.ndim == 3 else plant) > 0, "given"
    else:
        centre_mm = camera_centre(rig.P_left) * (rig.metres_per_unit * 1000.0)
        plant = plant_mask_of(left_bgr, organized, camera_centre_mm=centre_mm, index=index)
        source = "automatic"
    k = 1e-3 / rig.metres_per_unit  # millimetres -> world units
    camera_mm = np.asarray(rig.P_left, np.float64) @ np.diag([k, k, k, 1.0])
    scene = measure_scene(organized, leaf_ids=leaf_ids, mask=None if whole_scene else plant, ground=ground,
                          unit="mm", camera=camera_mm, voxel_size=voxel_size_mm)
    report = lab_report(scene.report)
    report["source"]["mask"] = source
    return PlantMeasurement(report=report, scene=scene, mask=plant, mask_source=source, organized_mm=organized)


#: What each mask source means, for the summaries.
_MASK_WORDS = {"given": "the given mask", "automatic": "the automatic plant mask",
               "whole scene": "every point (whole scene, no plant mask)"}


def measurement_lines(report: dict, *, max_leaves: int = 8) -> list[str]:
    """Summary lines of a :func:`measure_plant` report, in the one unit set (mm, cm^2, cm^3):
    what was measured, the canopy, the leaves (the first ``max_leaves``)."""
    c = report["canopy"]
    frame = report.get("frame", {}).get("kind", "?")
    lines = [f"measured: {_MASK_WORDS.get(report['source'].get('mask'), report['source'].get('mask'))}; "
             f"reference: {frame}; voxels {c['voxel_size']:g} mm",
             f"canopy: height {c['height']:.0f} mm, width {c['width']:.0f} mm, depth {c['depth']:.0f} mm"
             + (f", top {c['top_above_ground']:.0f} mm above the ground"
                if c.get("top_above_ground") is not None else ""),
             f"  volumes: convex hull {c['hull_volume']:.0f} cm^3, voxels {c['voxel_volume']:.0f} cm^3; "
             f"leaves measured: {c.get('n_leaves', 0)}"
             + (f", leaf area {c['leaf_area']:.0f} cm^2" if c.get("leaf_area") else "")]
    leaves = report.get("leaves", [])
    for leaf in leaves[:max_leaves]:
        lines.append(f"  leaf {leaf['id']}: length {leaf['length']:.0f} mm, width {leaf['width']:.0f} mm, "
                     f"area {leaf['area']:.1f} cm^2")
    if len(leaves) > max_leaves:
        lines.append(f"  ... {len(leaves) - max_leaves} more leaves")
    return lines


def write_overlay(path, measured: PlantMeasurement, left_bgr, *, caption: str = ""):
    """Write the mask overlay picture (:func:`~canopy_stereo.viz.overlay.mask_overlay`) of a
    measurement over its (original) left image; returns the path."""
    from canopy_stereo.io.images import write_image
    from canopy_stereo.viz.overlay import mask_overlay

    words = _MASK_WORDS.get(measured.mask_source, measured.mask_source)
    return write_image(path, mask_overlay(left_bgr, measured.mask, caption=caption or words))
