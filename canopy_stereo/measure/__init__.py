"""Measurement of leaves and canopies in organized clouds.

``measure_organized(organized, leaf_ids=None, mask=None, ground="auto", unit="mm", ...)``
returns the REPORT.json dict; :func:`write_report` writes it (and a per-leaf
CSV); :func:`measure_leaf` measures one leaf; :func:`plot_views` draws top and
side views with the measured dimensions.

Modules, one job each: :mod:`.instances` (leaf instances in the organized cloud),
:mod:`.leaf` (one leaf's size), :mod:`.cleaning` (matching debris off the canopy),
:mod:`.frame` (the measuring frame: ground, up), :mod:`.canopy` (extents, volumes),
:mod:`.scene` (one cloud measured: the REPORT.json dict), :mod:`.plants` (each plant of
a scene measured on its own, height from its pot rim or soil), :mod:`.report` (REPORT.json
and CSV written, clouds read), :mod:`.plot` (pictures); :mod:`.surface`,
:mod:`.sections`, :mod:`.geodesic`, :mod:`.viewpoint` serve them.
"""
from canopy_stereo.measure.canopy import canopy_dimensions, hull_volume, voxel_volume
from canopy_stereo.measure.frame import MeasuringFrame
from canopy_stereo.measure.instances import separate_leaves
from canopy_stereo.measure.leaf import LeafMeasurement, measure_leaf
from canopy_stereo.measure.plants import REFERENCE_KINDS, measure_plants, reference_surface
from canopy_stereo.measure.plot import plot_views
from canopy_stereo.measure.report import load_cloud, write_leaves_csv, write_report
from canopy_stereo.measure.scene import SceneMeasurement, measure_organized, measure_points, measure_scene
from canopy_stereo.measure.units import LAB_UNITS, lab_report
from canopy_stereo.measure.viewpoint import estimate_camera

__all__ = [
    "LAB_UNITS", "LeafMeasurement", "lab_report", "MeasuringFrame", "SceneMeasurement", "canopy_dimensions",
    "estimate_camera",
    "hull_volume", "load_cloud", "measure_leaf", "measure_organized", "measure_points",
    "measure_scene", "plot_views", "REFERENCE_KINDS", "measure_plants", "reference_surface", "separate_leaves",
    "voxel_volume", "write_leaves_csv", "write_report",
]
