"""Every setting of the quasi-dense matcher, in one frozen dataclass (:class:`QuasiDenseParams`)."""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.result import DISTRIBUTION_CELL_PX


@dataclass(frozen=True)
class QuasiDenseParams:
    """Settings of :func:`~canopy_stereo.features.quasi_dense.matching.qdmatch` (pixels, grey
    levels, shares as stated).

    Attributes:
        ratio, mutual, f_method, threshold_px: seed matching and verification; the
            final F check of the resampled matches uses ``f_method``/``threshold_px``.
        half_window, radius, eps, zncc_min, texture_min,
        directional_texture: propagation (see :func:`~.propagation.propagate`); the band and the
            directional texture use the seeds' F. ``texture_min`` is 0.7 grey levels
            per pixel (propagate's own default is 2): with the aperture and interior
            checks, weakly textured leaf and pot surfaces propagate without letting
            wrong matches through (Plants 23.6 -> 27 % of the cells, Middlebury mean
            95.5 -> 96.5 % correct).
        reseed_rounds, reseed_zncc_min, reseed_margin: extra propagation passes from
            epipolar-search seeds in unreached textured regions (see :func:`~.propagation.propagate`).
        epipolar_band_px: half-width (pixels) of the band around the seeds' epipolar
            lines that propagated matches must lie in. 0.6 px keeps the integer
            candidates of a nearly rectified pair to the row nearest the line: a band of
            1 px lets a slanted edge match one row off, pixels off in disparity.
        few_seeds, few_seeds_band_px: with fewer than ``few_seeds`` verified seeds the
            F is less certain and the band is widened to ``few_seeds_band_px``.
        aperture_max: propagation only through windows whose aperture coupling (see
            :func:`~.windows.aperture_coupling`) is at most this (None: no limit); it keeps integer
            matches off edges nearly along the epipolar lines, where a fraction of a pixel
            of row offset becomes pixels of disparity error.
        cell_px, model, resample_iters, resample_tol_px, min_support,
        min_inlier_share, min_spread_px, thin_spread_px, anchor, interior_px,
        interior_tol_px, interior_shape: resampling (see :func:`~.resampling.resample`).
        anchor_aperture_max: a region's match is placed only on a pixel whose aperture
            coupling is at most this (None: anywhere).
        sift_params: arguments of ``cv2.SIFT_create``.
        keep_propagation: store the :class:`Propagation` in ``extras["propagation"]``.
    """

    ratio: float = 0.8
    mutual: bool = True
    f_method: str = 'ransac'
    threshold_px: float = 1.0
    half_window: int = 2
    radius: int = 1
    eps: int = 1
    zncc_min: float = 0.8
    texture_min: float = 0.7
    epipolar_band_px: float | None = 0.6
    few_seeds: int = 100
    few_seeds_band_px: float = 1.0
    directional_texture: bool = True
    reseed_rounds: int = 2
    reseed_zncc_min: float = 0.9
    reseed_margin: float = 0.1
    cell_px: int = DISTRIBUTION_CELL_PX
    model: str = 'affine'
    resample_iters: int = 32
    resample_tol_px: float = 1.0
    min_support: int = 8
    min_inlier_share: float = 0.8
    min_spread_px: float = 1.0
    thin_spread_px: float = 0.0
    anchor: str = 'centroid'
    interior_px: int = 3
    interior_tol_px: float = 1.0
    interior_shape: str = 'line'
    aperture_max: float | None = 2.0
    anchor_aperture_max: float | None = 1.0
    sift_params: dict | None = None
    keep_propagation: bool = False

    def replace(self, **changes) -> QuasiDenseParams:
        """A copy with ``changes``; :class:`~canopy_stereo.errors.CanopyStereoError` for a name
        that is not a setting."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise CanopyStereoError(f"unknown qdmatch parameter {unknown[0]!r}; known: {', '.join(sorted(known))}")
        return replace(self, **changes) if changes else self
