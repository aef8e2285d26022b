"""Feature matching for stereo pairs: the paper's matcher study and quasi-dense matching.

* :func:`match_pair` -- verified matches of a pair with one method (``sift``,
  ``asift``, ``orb``, ``akaze``, ``kaze``, ``surf``, ``harris-affine``,
  ``hessian-affine``, ``qdmatch``) as a :class:`MatchResult`.
* :func:`estimate_fundamental` -- robust F (RANSAC / MAGSAC) from matches.
* :func:`distribution` -- the paper's spread measure (share of 8 x 8-pixel cells used).
* :func:`run_study` -- every method on one pair, scored against a ground-truth
  disparity or the pooled epipolar geometry (the ``canopy-stereo features`` table).

Modules: :mod:`~canopy_stereo.features.quasi_dense` (propagation and resampling,
numba), :mod:`~canopy_stereo.features.asift`,
:mod:`~canopy_stereo.features.affine_regions` (Harris/Hessian-affine),
:mod:`~canopy_stereo.features.detectors` (OpenCV keypoints); pairs with known disparity
for checking them: :mod:`canopy_stereo.sim.stereo_pair`.
"""
from canopy_stereo.features.api import METHODS, available_methods, check_method, match_pair, method_available
from canopy_stereo.features.result import DISTRIBUTION_CELL_PX, MatchResult, distribution
from canopy_stereo.features.study import StudyRow, run_study
from canopy_stereo.geometry.fundamental import epipolar_distance, estimate_fundamental

__all__ = [
    "DISTRIBUTION_CELL_PX", "METHODS", "MatchResult", "available_methods", "check_method",
    "distribution", "epipolar_distance", "estimate_fundamental", "match_pair", "method_available",
    "StudyRow", "run_study",
]
