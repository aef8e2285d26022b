"""Sparse matching pipeline shared by the keypoint methods.

detect (left: t1, right: t2) -> nearest neighbour + ratio test + mutual check ->
geometric verification by a robust fundamental matrix (t).
"""
from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from canopy_stereo.errors import MatchingError
from canopy_stereo.features.descriptor_matching import match_descriptors
from canopy_stereo.features.detectors import Features
from canopy_stereo.features.result import MatchResult
from canopy_stereo.geometry.fundamental import MIN_MATCHES_F, estimate_fundamental


def verify_matches(x_left: np.ndarray, x_right: np.ndarray, *, f_method: str = "ransac",
                   threshold_px: float = 1.0):
    """Keep the matches that agree with one robust F: ``(F or None, keep_mask, note)``.

    With fewer than 8 matches nothing can be verified: all are dropped and the
    note says why.
    """
    n = len(x_left)
    if n < MIN_MATCHES_F:
        return None, np.zeros(n, bool), (
            f"only {n} tentative matches: too few to verify with a fundamental matrix")
    try:
        F, inliers = estimate_fundamental(x_left, x_right, method=f_method, threshold_px=threshold_px)
    except MatchingError as exc:
        return None, np.zeros(n, bool), str(exc)
    return F, inliers, ""


def sparse_match(left_gray: np.ndarray, right_gray: np.ndarray, method: str,
                 detect: Callable[[np.ndarray], Features], *, ratio: float = 0.8,
                 mutual: bool = True, f_method: str = "ransac",
                 threshold_px: float = 1.0, match: Callable | None = None) -> MatchResult:
    """Detect, match and verify keypoints of a grey pair; one :class:`MatchResult` row.

    Args:
        left_gray, right_gray: uint8 (H, W) images of the same size.
        method: name stored in the result.
        detect: grey image -> :class:`Features`.
        ratio, mutual: descriptor matching (see :func:`match_descriptors`).
        f_method, threshold_px: geometric verification (see :func:`estimate_fundamental`).
        match: optional ``(features_left, features_right) -> (idx_left, idx_right)``
            replacing plain descriptor matching (ASIFT's location-aware matching).
    """
    size = (left_gray.shape[1], left_gray.shape[0])
    t0 = time.perf_counter()
    feat_l = detect(left_gray)
    t1 = time.perf_counter()
    feat_r = detect(right_gray)
    t2 = time.perf_counter()
    if match is None:
        il, ir = match_descriptors(feat_l.descriptors, feat_r.descriptors, ratio=ratio,
                                   mutual=mutual, binary=feat_l.binary)
    else:
        il, ir = match(feat_l, feat_r)
    xl, xr = feat_l.points[il], feat_r.points[ir]
    F, keep, note = verify_matches(xl, xr, f_method=f_method, threshold_px=threshold_px)
    t3 = time.perf_counter()
    if len(feat_l) == 0 or len(feat_r) == 0:
        note = (f"no {method} features in the {'left' if len(feat_l) == 0 else 'right'} image "
                "(no texture?)")
    elif not keep.any() and not note:
        note = f"no {method} matches survived verification"
    return MatchResult(method=method, x_left=xl[keep], x_right=xr[keep], image_size=size,
                       num_left=len(feat_l), num_right=len(feat_r), t_left=t1 - t0,
                       t_right=t2 - t1, t_match=t3 - t2, F=F, note=note,
                       extras={"num_tentative": int(len(il))})
