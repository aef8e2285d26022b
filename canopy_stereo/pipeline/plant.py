"""A raw stereo pair reconstructed and measured by the package's one measuring pipeline.

:func:`measure_stereo_pair`: :func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`
then :func:`canopy_stereo.measure.plant.measure_plant` on its rectified left image and
disparity (``batch`` and ``reconstruct --measure`` measure this way; ``demo``, ``view`` and
the nodes hand ``measure_plant`` the graph's rectified image and disparity).
"""
from __future__ import annotations

from canopy_stereo.disparity import DEFAULT_MATCHER
from canopy_stereo.measure.plant import DEFAULT_COLOUR_INDEX, DEFAULT_GROUND, DEFAULT_VOXEL_SIZE_MM, measure_plant


def measure_stereo_pair(left_bgr, right_bgr, rig, *, matcher: str = DEFAULT_MATCHER, method: str | None = None,
                        disp_min=None, disp_max=None, near_m=None, far_m=None, mask=None, leaf_ids=None,
                        whole_scene: bool = False, index: str = DEFAULT_COLOUR_INDEX, ground=DEFAULT_GROUND,
                        voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM):
    """A raw stereo pair reconstructed (:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair`)
    and measured (:func:`measure_plant`); ``mask``/``leaf_ids`` on the ORIGINAL left image.
    Returns ``(reconstruction, PlantMeasurement)``."""
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rec = reconstruct_pair(left_bgr, right_bgr, rig, method=method, matcher=matcher,
                           disp_min=disp_min, disp_max=disp_max, near_m=near_m, far_m=far_m)
    measured = measure_plant(left_bgr, rec.disparity, rig, rectification=rec.rectification, mask=mask,
                             leaf_ids=leaf_ids,
                             whole_scene=whole_scene, index=index, ground=ground, voxel_size_mm=voxel_size_mm)
    return rec, measured
