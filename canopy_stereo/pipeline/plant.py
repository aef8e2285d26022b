"""The one measuring pipeline: a rectified left image and its disparity -> the plant's traits.

Every entry point that measures calls :func:`measure_plant` with the same defaults
(``canopy-stereo reconstruct --measure``, ``batch``, ``demo``, ``view``, ``paper`` and the
measuring nodes), so the same stereo pair and options give the same numbers everywhere:

1. the cloud: the rectified disparity triangulated with the rig's world-frame ``P``
   (:func:`~canopy_stereo.geometry.triangulation.triangulate_disparity_points`, the
   point cloud node's computation), one point per rectified left pixel, millimetres;
2. the plant mask (:func:`plant_mask_of`, the one place the automatic segmentation is
   called): a given mask, the automatic plant mask (default), or the whole scene;
3. the measurement (:func:`~canopy_stereo.measure.measure_scene`: leaves separated and
   measured, canopy cleaned, ground reference ``ground``, voxel edge ``voxel_size_mm``);
4. the report in the package's one unit set (:func:`~canopy_stereo.measure.lab_report`):
   lengths mm, areas cm^2, volumes cm^3.

The grid is the rectified left image's: what the graph's nodes publish
(``left/image_rect_color``, ``disparity``) and what :func:`reconstruct_pair` computes
(``rec.rectified[0]``, ``rec.disparity``); :func:`measure_stereo_pair` does both steps for
a raw pair. Masks and leaf-id images drawn on the original left image are carried over
with :func:`to_rectified_grid`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canopy_stereo.disparity import DEFAULT_MATCHER
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
        scene: the :class:`~canopy_stereo.measure.SceneMeasurement` (millimetres) the
            report came from, for :func:`~canopy_stereo.measure.plot_views`.
        mask: (Hr, Wr) bool plant mask on the rectified left grid (all True for the whole scene).
        mask_source: one of :data:`MASK_SOURCES`.
        organized_mm: (Hr, Wr, 3) float64 world points (mm) of the rectified left pixels, NaN = none.
    """

    report: dict
    scene: object
    mask: np.ndarray
    mask_source: str
    organized_mm: np.ndarray


def rectified_cloud_mm(disparity, rig, rectification: Rectification) -> np.ndarray:
    """(Hr, Wr, 3) float64 world points in millimetres of a rectified left disparity
    (pixels ``u_left - u_right``; negative or NaN = none), NaN where no point."""
    from canopy_stereo.geometry.triangulation import triangulate_disparity_points

    disp = np.asarray(disparity, np.float32)
    pts, _ = triangulate_disparity_points(disp, rectification, rig.P_left, rig.P_right,
                                          scale=rig.metres_per_unit * 1000.0, organized=True)
    return np.asarray(pts, np.float64).reshape(disp.shape + (3,))


def rectified_camera_mm(rig, rectification: Rectification) -> np.ndarray:
    """(3, 4) projection of world millimetres to rectified left pixels (``H_left P_left``)."""
    k = 1e-3 / rig.metres_per_unit
    return rectification.H_left @ np.asarray(rig.P_left, np.float64) @ np.diag([k, k, k, 1.0])


def to_rectified_grid(image, rig, rectification: Rectification) -> np.ndarray:
    """A label image drawn on the original left image (mask, leaf ids) carried to the
    rectified left grid, nearest neighbour (undistortion included); 0 outside."""
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


def plant_mask_of(left_rect_bgr, organized_mm, *, camera_centre_mm, index: str = DEFAULT_COLOUR_INDEX) -> np.ndarray:
    """The automatic plant mask (bool (Hr, Wr)) of a rectified left image and its cloud
    (mm; ``camera_centre_mm`` (3,) the left camera's centre, mm): the one place the
    measuring pipeline calls the automatic segmentation (colour cue ``index`` with the
    distance from the camera as the depth cue)."""
    from canopy_stereo.segmentation import auto_plant_mask

    if int(np.all(np.isfinite(organized_mm), axis=-1).sum()) < 3:
        raise CanopyStereoError("no 3D point to find the plant by (the disparity is empty)")
    distance = np.linalg.norm(organized_mm - np.asarray(camera_centre_mm, np.float64), axis=-1)
    return auto_plant_mask(left_rect_bgr, depth=distance, index=index) > 0


def plant_mask_on_original(rec, rig, mask_rect) -> np.ndarray:
    """(H, W) bool: the original left pixels of a :class:`~canopy_stereo.pipeline.reconstruct.Reconstruction`
    whose rectified match lies on ``mask_rect`` (a rectified-grid plant mask): the
    disparity outside the mask dropped, the rest mapped back as ``reconstruct_pair`` maps it."""
    from canopy_stereo.geometry.triangulation import organized_from_disparity

    disp = np.where(np.asarray(mask_rect) > 0, rec.disparity, np.float32(-1))
    org = organized_from_disparity(disp, rec.rectification, rig.P_left, rig.P_right, rig.image_size,
                                   D_left=rig.D_left)
    return np.all(np.isfinite(org), axis=-1) & np.all(np.isfinite(rec.organized), axis=-1)


def automatic_plant_mask(rec, rig, *, index: str = DEFAULT_COLOUR_INDEX) -> np.ndarray:
    """The automatic plant mask of a reconstruction, on its RECTIFIED left grid (bool (Hr, Wr)):
    :func:`plant_mask_of` of ``rec.rectified[0]`` and the cloud of ``rec.disparity``, as
    :func:`measure_plant` finds it."""
    from canopy_stereo.geometry.camera import camera_centre

    org = rectified_cloud_mm(rec.disparity, rig, rec.rectification)
    centre_mm = camera_centre(rig.P_left) * (rig.metres_per_unit * 1000.0)
    return plant_mask_of(rec.rectified[0], org, camera_centre_mm=centre_mm, index=index)


def measure_plant(left_rect_bgr, disparity, rig, *, rectification: Rectification, mask=None,
                  leaf_ids=None, whole_scene: bool = False, index: str = DEFAULT_COLOUR_INDEX,
                  ground=DEFAULT_GROUND, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> PlantMeasurement:
    """Measure the plant of one rectified stereo frame (the package's one measuring pipeline).

    Args:
        left_rect_bgr: (Hr, Wr, 3) uint8 rectified left image (BGR).
        disparity: (Hr, Wr) rectified left disparity, pixels; negative or NaN = none.
        rig: :class:`~canopy_stereo.io.rig.Rig` (any world unit).
        rectification: the :class:`Rectification` of the disparity.
        mask: optional (Hr, Wr) plant mask on the rectified grid (non-zero = plant); default:
            the automatic plant mask (:func:`plant_mask_of`).
        leaf_ids: optional (Hr, Wr) leaf-id image on the rectified grid (0 = none).
        whole_scene: measure every point (no plant mask, the old behaviour).
        index: colour cue of the automatic mask.
        ground: ground reference of the heights (``"auto"``, ``"none"``, ...).
        voxel_size_mm: voxel edge of the occupancy volume, millimetres (> 0).

    Returns a :class:`PlantMeasurement`; raises :class:`CanopyStereoError` with one line
    when there is nothing to measure.
    """
    from canopy_stereo.measure import lab_report, measure_scene

    if not (np.isfinite(voxel_size_mm) and voxel_size_mm > 0):
        raise CanopyStereoError(f"voxel size must be > 0 mm, got {voxel_size_mm}")
    if whole_scene and mask is not None:
        raise CanopyStereoError("a mask and the whole scene exclude each other")
    organized = rectified_cloud_mm(disparity, rig, rectification)
    if whole_scene:
        plant, source = np.ones(organized.shape[:2], bool), "whole scene"
    elif mask is not None:
        plant, source = np.asarray(mask) > 0, "given"
        if plant.ndim == 3:
            plant = plant.any(axis=2)
    else:
        from canopy_stereo.geometry.camera import camera_centre

        centre_mm = camera_centre(rig.P_left) * (rig.metres_per_unit * 1000.0)
        plant = plant_mask_of(left_rect_bgr, organized, camera_centre_mm=centre_mm, index=index)
        source = "automatic"
    scene = measure_scene(organized, leaf_ids=leaf_ids, mask=None if whole_scene else plant, ground=ground,
                          unit="mm", camera=rectified_camera_mm(rig, rectification), voxel_size=voxel_size_mm)
    report = lab_report(scene.report)
    report["source"]["mask"] = source
    report["source"]["grid"] = "rectified left"
    return PlantMeasurement(report=report, scene=scene, mask=plant, mask_source=source, organized_mm=organized)


def measure_stereo_pair(left_bgr, right_bgr, rig, *, matcher: str = DEFAULT_MATCHER, method: str | None = None,
                        disp_min=None, disp_max=None, near_m=None, far_m=None, mask=None, leaf_ids=None, whole_scene: bool = False,
                        index: str = DEFAULT_COLOUR_INDEX, ground=DEFAULT_GROUND,
                        voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM):
    """A raw stereo pair reconstructed (:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`)
    and measured (:func:`measure_plant`); ``mask``/``leaf_ids`` on the ORIGINAL left image.
    Returns ``(reconstruction, PlantMeasurement)``."""
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rec = reconstruct_pair(left_bgr, right_bgr, rig, method=method, matcher=matcher,
                           disp_min=disp_min, disp_max=disp_max, near_m=near_m, far_m=far_m)
    rect = rec.rectification
    m_r = None if mask is None else to_rectified_grid(mask, rig, rect)
    ids_r = None if leaf_ids is None else to_rectified_grid(leaf_ids, rig, rect)
    measured = measure_plant(rec.rectified[0], rec.disparity, rig, rectification=rect, mask=m_r, leaf_ids=ids_r,
                             whole_scene=whole_scene, index=index, ground=ground, voxel_size_mm=voxel_size_mm)
    return rec, measured


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


def write_overlay(path, measured: PlantMeasurement, left_rect_bgr, *, caption: str = ""):
    """Write the mask overlay picture (:func:`~canopy_stereo.viz.overlay.mask_overlay`) of a
    measurement over its rectified left image; returns the path."""
    from canopy_stereo.io.images import write_image
    from canopy_stereo.viz.overlay import mask_overlay

    words = _MASK_WORDS.get(measured.mask_source, measured.mask_source)
    return write_image(path, mask_overlay(left_rect_bgr, measured.mask, caption=caption or words))
