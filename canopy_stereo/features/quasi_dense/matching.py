"""The quasi-dense matcher (:func:`qdmatch`): SIFT seeds -> propagation -> resampling."""
from __future__ import annotations

import time

import numpy as np

from canopy_stereo.errors import MatchingError
from canopy_stereo.features.descriptor_matching import match_descriptors
from canopy_stereo.features.detectors import detect_and_describe, make_detector
from canopy_stereo.features.quasi_dense.params import QuasiDenseParams
from canopy_stereo.features.quasi_dense.propagation import propagate
from canopy_stereo.features.quasi_dense.resampling import resample
from canopy_stereo.features.quasi_dense.windows import aperture_coupling, epipoles
from canopy_stereo.features.result import MatchResult
from canopy_stereo.features.sparse import verify_matches
from canopy_stereo.geometry.fundamental import MIN_MATCHES_F, estimate_fundamental

# ----------------------------------------------------------------------------------------------
# The whole matcher


def sift_seeds(left_gray, right_gray, *, ratio=0.8, mutual=True, f_method="ransac",
               threshold_px=1.0, sift_params=None):
    """Verified SIFT matches for seeding, with timings.

    Returns a dict: ``x_left``, ``x_right`` (S, 2), ``F`` (or None), ``num_left``,
    ``num_right``, ``t_left``, ``t_right``, ``t_match``, ``note``.
    """
    det = make_detector("sift", **(sift_params or {}))
    t0 = time.perf_counter()
    fl = detect_and_describe(left_gray, "sift", detector=det)
    t1 = time.perf_counter()
    fr = detect_and_describe(right_gray, "sift", detector=det)
    t2 = time.perf_counter()
    il, ir = match_descriptors(fl.descriptors, fr.descriptors, ratio=ratio, mutual=mutual)
    xl, xr = fl.points[il], fr.points[ir]
    F, keep, note = verify_matches(xl, xr, f_method=f_method, threshold_px=threshold_px)
    t3 = time.perf_counter()
    return dict(x_left=xl[keep], x_right=xr[keep], F=F, num_left=len(fl), num_right=len(fr),
                t_left=t1 - t0, t_right=t2 - t1, t_match=t3 - t2, note=note)


def qdmatch(left_gray: np.ndarray, right_gray: np.ndarray, *, params: QuasiDenseParams | None = None,
            **options) -> MatchResult:
    """Quasi-dense matches of a grey pair (SIFT seeds -> propagation -> resampling).

    Args:
        left_gray, right_gray: uint8 (H, W) images of the same size.
        params: every setting (default :class:`QuasiDenseParams`, the tuned defaults).
        **options: settings by name, over ``params`` (``qdmatch(l, r, ratio=0.7)``); an
            unknown name is a :class:`~canopy_stereo.errors.CanopyStereoError`.

    Returns:
        :class:`MatchResult` (method ``"qdmatch"``) whose matches are the resampled
        region centres; ``t_propagation``/``t_resample`` are timed separately and
        ``extras`` holds ``num_seeds`` and ``num_propagated``. Without seeds (no
        texture) the result is empty and ``note`` says why.
    """
    p = (params or QuasiDenseParams()).replace(**options)
    size = (left_gray.shape[1], left_gray.shape[0])
    seeds = sift_seeds(left_gray, right_gray, ratio=p.ratio, mutual=p.mutual, f_method=p.f_method,
                       threshold_px=p.threshold_px, sift_params=p.sift_params)
    common = dict(method="qdmatch", image_size=size, num_left=seeds["num_left"],
                  num_right=seeds["num_right"], t_left=seeds["t_left"],
                  t_right=seeds["t_right"], t_match=seeds["t_match"])
    if len(seeds["x_left"]) == 0:
        why = seeds["note"] or "no verified SIFT matches"
        if seeds["num_left"] == 0 or seeds["num_right"] == 0:
            why = (f"SIFT found {seeds['num_left']} keypoints in the left and "
                   f"{seeds['num_right']} in the right image")
        return MatchResult(x_left=np.zeros((0, 2)), x_right=np.zeros((0, 2)),
                           note=f"no seeds for propagation ({why}; image without texture?)",
                           extras={"num_seeds": 0, "num_propagated": 0}, **common)
    t0 = time.perf_counter()
    F_prop = seeds["F"]
    band = p.epipolar_band_px
    if band is not None and len(seeds["x_left"]) < p.few_seeds:
        band = max(band, p.few_seeds_band_px)
    prop = propagate(left_gray, right_gray, seeds["x_left"], seeds["x_right"],
                     half_window=p.half_window, radius=p.radius, eps=p.eps, zncc_min=p.zncc_min,
                     texture_min=p.texture_min, F=F_prop, epipolar_band_px=band,
                     directional_texture=p.directional_texture, reseed_rounds=p.reseed_rounds,
                     reseed_zncc_min=p.reseed_zncc_min, reseed_margin=p.reseed_margin,
                     aperture_max=p.aperture_max)
    t1 = time.perf_counter()
    amask, e_l = None, None
    if F_prop is not None:
        e_l, _ = epipoles(np.asarray(F_prop, np.float64))
        if p.anchor_aperture_max is not None:
            amask = aperture_coupling(left_gray, p.half_window, e_l) <= p.anchor_aperture_max
    xl, xr, support = resample(prop, cell_px=p.cell_px, model=p.model, iters=p.resample_iters,
                               tol_px=p.resample_tol_px, min_support=p.min_support,
                               min_inlier_share=p.min_inlier_share, min_spread_px=p.min_spread_px,
                               thin_spread_px=p.thin_spread_px, anchor=p.anchor,
                               interior_px=p.interior_px, interior_tol_px=p.interior_tol_px,
                               interior_shape=p.interior_shape, anchor_mask=amask, epipole=e_l)
    F, note = seeds["F"], ""
    if len(xl) >= MIN_MATCHES_F:
        try:
            F, keep = estimate_fundamental(xl, xr, method=p.f_method, threshold_px=p.threshold_px)
            xl, xr, support = xl[keep], xr[keep], support[keep]
        except MatchingError as exc:
            note = f"resampled matches failed the F check: {exc}"
            xl, xr, support = xl[:0], xr[:0], support[:0]
    else:
        note = f"only {len(xl)} regions could be resampled"
    t2 = time.perf_counter()
    extras = {"num_seeds": prop.num_seeds, "num_propagated": len(prop), "support": support}
    if p.keep_propagation:
        extras["propagation"] = prop
    return MatchResult(x_left=xl, x_right=xr, F=F, note=note, t_propagation=t1 - t0,
                       t_resample=t2 - t1, extras=extras, **common)
