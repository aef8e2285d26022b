"""The paper's results reproduced on what the package ships (``canopy-stereo paper``).

:func:`run_paper` runs every experiment of Ni & Burks that the package can repeat
without the authors' photographs, writes the figures and a Markdown report that
puts each number of this run next to the number the paper prints, and returns the
run's numbers (also written as ``report.json``):

* Table 1 and Figure 5: the world-rig calibration on rendered photographs of the
  paper's layout (chessboard placements along three lines), through the paper's rig;
* Tables 2-4: the feature study (:mod:`canopy_stereo.features.study`) on the shipped
  plant pairs: Middlebury "Plants" (real, bundled; stands in for the aloe of
  Table 2), the synthetic citrus branch (small leaves; for the banyan of Table 3)
  and the synthetic croton (Table 4), with correctness against the exact
  correspondences of the rendered pairs;
* Figure 11: epipolar lines before and after Hartley rectification (from
  quasi-dense matches) of the rendered croton pair;
* Figures 15-17: rectified pairs and the reconstructed clouds as pictures (croton,
  the real Plants pair, the citrus branch);
* the two marked croton leaves (Figures 20-22): width and length measured on the
  reconstruction, against the rendered truth (the ruler: 97 x 160 and 86 x 145 mm)
  and the paper's MeshLab figures.

The only constants are the paper's printed numbers (:data:`PAPER_TABLE1`,
:data:`PAPER_FEATURE_TABLES`, :data:`PAPER_LEAVES`); everything else is measured by
the run. ``quick=True`` is the reduced mode for CI (fewer methods, placements and
scenes). Lengths are millimetres (the rigs' world unit).

Modules: :mod:`~canopy_stereo.pipeline.paper.numbers` (the paper's printed numbers),
:mod:`~canopy_stereo.pipeline.paper.data` (the shipped pairs), :mod:`~canopy_stereo.pipeline.paper.sections`
(one experiment each), :mod:`~canopy_stereo.pipeline.paper.run` (:func:`run_paper`),
:mod:`~canopy_stereo.pipeline.paper.report` (:func:`format_report`).
"""
from canopy_stereo.pipeline.paper.data import StereoPair, plants_pair, rendered_pair
from canopy_stereo.pipeline.paper.numbers import (
    FEATURE_SCENES,
    FULL_METHODS,
    PAPER_FEATURE_TABLES,
    PAPER_LEAVES,
    PAPER_TABLE1,
    QUICK_METHODS,
)
from canopy_stereo.pipeline.paper.report import format_report
from canopy_stereo.pipeline.paper.run import run_paper

__all__ = ["FEATURE_SCENES", "FULL_METHODS", "PAPER_FEATURE_TABLES", "PAPER_LEAVES", "PAPER_TABLE1",
           "QUICK_METHODS", "StereoPair", "format_report", "plants_pair", "rendered_pair",
           "run_paper"]
