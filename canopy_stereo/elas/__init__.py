"""ELAS dense stereo matching (Geiger, Roser, Urtasun: "Efficient Large-Scale Stereo
Matching", ACCV 2010), written from the paper and the stage description in
``elas.md``; hot loops in numba.

Main entry points: :func:`elas_disparity` (two maps), :func:`elas_run` (maps, support
points, triangles, stage timings) and :func:`~canopy_stereo.elas.matcher.elas_matcher`
(the registered ``elas`` matcher). Stages, one module each: :mod:`.descriptor`,
:mod:`.support`, :mod:`.delaunay` (with :mod:`.sweephull`), :mod:`.grid`,
:mod:`.matching`, :mod:`.postprocess`; :mod:`canopy_stereo.sim.stereo_pair` makes test pairs.

Measured with ``benchmarks/bench_elas.py`` (16 Middlebury pairs, 0..255 disparities):

* Against libelas (pyelas), per pair and preset: bad>2 within +0.5 points and density
  within -1 point on 30 of 32 pair-presets (misses: PlaytableQ middlebury bad>2 +1.7,
  VintageQ robotics density -4.4 with bad>2 4.2 points *better*).
* Time (``--target``: CPU time of one thread against libelas's, the same load, on the
  Middlebury 2014 training scenes; loaded machine): robotics 0.20-0.27x on the
  640x480-class scenes (median 0.23), middlebury 0.17-0.23x (median 0.19); bad>2 and
  density within 0.2 points of libelas's (or better) on 8 of 9
  scenes per preset (VintageQ and PlaytableQ as above).
* Threads: :mod:`.parallel` runs the row kernels in bands and the left/right stages as
  two tasks; the maps are the same bit for bit with any thread count.
* ``subpixel=True`` (parabola through the SAD at d-1, d, d+1, where d is also a local
  minimum of the SAD): on synthetic slanted planes the end-point error drops 2-4x
  (0.25 -> 0.07 px with the middlebury preset); on the Middlebury pairs it lowers the
  mean EPE by 2 % and bad>0.5 by 0.6 (robotics) / 3.4 (middlebury) points, but raises
  bad>2 of the middlebury preset by 0.7 points, so it is off by default.
* Adaptive-mean weights: the original as compiled (4 / 2 / 0, the default) and the
  intended ``max(0, 4 - |dd|)`` (``adaptive_mean_weights="linear"``) differ little:
  mean bad>1 13.62 vs 13.08 %, bad>2 8.61 vs 8.56 %, EPE 0.978 vs 0.976 px.
"""
from canopy_stereo.elas.core import ElasResult, ElasWarning, elas_disparity, elas_run
from canopy_stereo.elas.params import PRESETS, ElasParams, make_params

__all__ = ["PRESETS", "ElasParams", "ElasResult", "ElasWarning", "elas_disparity", "elas_run",
           "make_params"]
