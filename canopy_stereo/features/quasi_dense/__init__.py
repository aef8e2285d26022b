"""Quasi-dense matching (Lhuillier & Quan, PAMI 2005): seed propagation + resampling.

1. **Seeds**: verified SIFT matches (ratio test, mutual check, robust F),
   rounded to whole pixels.
2. **Propagation** (best first): a priority queue holds accepted matches keyed by
   their ZNCC. The best match ``(x, x')`` is popped; every left pixel ``u`` in its
   ``(2r+1) x (2r+1)`` neighbourhood is tried against the right pixels
   ``u' = u + (x' - x) + delta`` with ``|delta|_inf <= eps`` (the disparity-gradient
   limit). A candidate needs ZNCC over a small window above ``zncc_min``, texture
   above ``texture_min`` in both images (with the seeds' F: the window's mean
   gradient along the epipolar line, which rejects aperture-ambiguous windows;
   without F: the largest difference to a 4-neighbour, as in the paper) and, when
   F is known, ``u'`` within ``epipolar_band_px`` of the epipolar line of ``u``.
   Candidates are accepted best first when neither ``u`` nor ``u'`` is matched yet
   (uniqueness in both images) and are pushed on the queue in turn.
2b. **Reseeding**: a region without a SIFT seed of its own (a leaf separated from its
   neighbours by background) is never reached by growth alone. With F, textured left
   pixels far from every match are matched by a ZNCC search along their epipolar
   line within the displacements seen so far (a distinct peak, left-right
   consistent) and grow in a further pass; up to ``reseed_rounds`` passes.
3. **Resampling**: the left image is cut into ``cell_px`` x ``cell_px`` regions; a
   local affine map (or homography) is fitted by RANSAC to the propagated matches
   of each region, and a region whose fit explains at least ``min_inlier_share``
   of its matches and whose inliers spread over an area (a thin line of matches
   is accepted only where no match nearby disagrees with the fit: one surface, not
   an occlusion edge) emits one match: its centre (when the inliers surround it)
   or the inliers' centroid, and that point's image under the map. A final robust
   F over the resampled matches removes the inconsistent ones.
   Two checks keep the matches correct (>= 95 % within 1 px of Middlebury's ground
   truth): windows whose only structure is an edge nearly along the epipolar line
   are not propagated into and carry no match (:func:`aperture_coupling`: with rows a
   fraction of a pixel apart an integer match there is pixels off), and a region's
   match is placed on an inlier whose neighbours along the epipolar line are matched
   consistently further than the ZNCC window reaches (``interior_px``): the band a
   window smears a foreground's displacement into past a depth edge emits nothing.

The propagation and the resampling are numba kernels (single thread: the
propagation is inherently sequential); the propagation caches each left pixel's
candidate ZNCCs for the last displacement it was reached with. Pixels: ``u`` right, ``v`` down, top-left
pixel centre at (0, 0).

Modules: :mod:`~canopy_stereo.features.quasi_dense.windows` (ZNCC and texture windows),
:mod:`~canopy_stereo.features.quasi_dense.propagation` (steps 1-2b),
:mod:`~canopy_stereo.features.quasi_dense.resampling` (step 3),
:mod:`~canopy_stereo.features.quasi_dense.params` (:class:`QuasiDenseParams`, every setting),
:mod:`~canopy_stereo.features.quasi_dense.matching` (:func:`qdmatch`, the whole matcher).
"""
from canopy_stereo.features.quasi_dense.matching import qdmatch, sift_seeds
from canopy_stereo.features.quasi_dense.params import QuasiDenseParams
from canopy_stereo.features.quasi_dense.propagation import Propagation, epipolar_seeds, propagate
from canopy_stereo.features.quasi_dense.resampling import resample
from canopy_stereo.features.quasi_dense.windows import aperture_coupling, epipoles, texture_map, window_statistics

__all__ = ["Propagation", "QuasiDenseParams", "aperture_coupling", "epipolar_seeds", "epipoles", "propagate",
           "qdmatch", "resample", "sift_seeds", "texture_map", "window_statistics"]
