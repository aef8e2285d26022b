"""``match_pair``: one entry point for every matcher of the study.

Methods (see :func:`available_methods`):

* ``sift``, ``orb``, ``akaze``, ``kaze``, ``surf``: OpenCV keypoints (AKAZE/KAZE/SURF
  only where the installed OpenCV has them);
* ``asift``: affine simulation + SIFT (Morel & Yu);
* ``harris-affine``, ``hessian-affine``: Mikolajczyk & Schmid affine regions with
  SIFT descriptors on the normalised patches;
* ``qdmatch``: Lhuillier & Quan quasi-dense propagation from SIFT seeds + resampling.

All sparse methods: nearest neighbour + ratio test + mutual check, then a robust
fundamental matrix keeps the geometrically consistent matches.
"""
from __future__ import annotations

import importlib

import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError, MatchingError
from canopy_stereo.features.detectors import detect_and_describe, detector_available, make_detector
from canopy_stereo.features.result import MatchResult
from canopy_stereo.features.sparse import sparse_match
from canopy_stereo.geometry.fundamental import MIN_MATCHES_F
from canopy_stereo.io.images import check_pair, to_gray

#: Study order of the methods (the paper's Tables 2-4 plus ORB/AKAZE/KAZE).
METHODS = ("harris-affine", "hessian-affine", "sift", "asift", "surf", "orb", "akaze", "kaze",
           "qdmatch")

#: Methods built on an OpenCV detector of the same name.
_OPENCV_METHODS = ("sift", "orb", "akaze", "kaze", "surf")

# Methods implemented in their own module: name -> "module:function(left_gray, right_gray, **kw)".
_MODULE_METHODS = {
    "asift": "canopy_stereo.features.asift:asift_match",
    "harris-affine": "canopy_stereo.features.affine_regions:harris_affine_match",
    "hessian-affine": "canopy_stereo.features.affine_regions:hessian_affine_match",
    "qdmatch": "canopy_stereo.features.quasi_dense.matching:qdmatch",
}


def method_available(method: str) -> tuple[bool, str]:
    """``(available, reason)``: whether ``method`` can run with the installed OpenCV."""
    check_method(method)
    if method in _OPENCV_METHODS:
        return detector_available(method)
    return True, ""


def available_methods() -> list[str]:
    """Names of the methods that run here, in study order."""
    return [m for m in METHODS if method_available(m)[0]]


def check_method(method: str) -> str:
    """Return ``method`` or raise :class:`CanopyStereoError` naming the valid ones."""
    if method not in METHODS:
        raise CanopyStereoError(f"unknown matching method {method!r}; choose one of {', '.join(METHODS)}")
    return method


def _prepare_pair(left, right):
    left, right = np.asarray(left), np.asarray(right)
    for name, img in (("left", left), ("right", right)):
        if img.dtype != np.uint8:
            raise ImageError(f"{name} image must be uint8, got {img.dtype}")
    check_pair(left, right)
    return to_gray(left, "left"), to_gray(right, "right")


def match_pair(left: np.ndarray, right: np.ndarray, *, method: str = "sift", ratio: float = 0.8,
               mutual: bool = True, f_method: str = "ransac", threshold_px: float = 1.0,
               min_matches: int = MIN_MATCHES_F, **params) -> MatchResult:
    """Verified point matches of a stereo pair with one method of the study.

    Args:
        left, right: uint8 images (grey or BGR) of the same size; original
            (unrectified) or rectified.
        method: one of :data:`METHODS`.
        ratio: nearest-neighbour ratio-test threshold.
        mutual: require mutual nearest neighbours.
        f_method: ``"ransac"`` or ``"magsac"`` for the geometric verification.
        threshold_px: verification threshold, pixels from the epipolar line.
        min_matches: raise :class:`MatchingError` when fewer verified matches
            remain (0: never raise; the study uses this to print empty rows).
        **params: method parameters (OpenCV detector arguments for the OpenCV
            methods; see :func:`canopy_stereo.features.quasi_dense.matching.qdmatch` (settings:
            :class:`~canopy_stereo.features.quasi_dense.params.QuasiDenseParams`),
            :func:`~canopy_stereo.features.asift.asift_match`, ...).

    Returns:
        :class:`MatchResult` with ``x_left``/``x_right`` (N, 2) float64 pixels.

    Raises:
        CanopyStereoError: unknown or unavailable method, bad parameters.
        ImageError: non-uint8 images or different sizes.
        MatchingError: fewer than ``min_matches`` verified matches (message says why).
    """
    check_method(method)
    ok, reason = method_available(method)
    if not ok:
        raise CanopyStereoError(reason)
    left_g, right_g = _prepare_pair(left, right)
    if method in _OPENCV_METHODS:
        detector = make_detector(method, **params)

        def detect(gray):
            return detect_and_describe(gray, method, detector=detector)

        result = sparse_match(left_g, right_g, method, detect, ratio=ratio, mutual=mutual,
                              f_method=f_method, threshold_px=threshold_px)
    else:
        module, func = _MODULE_METHODS[method].split(":")
        fn = getattr(importlib.import_module(module), func)
        result = fn(left_g, right_g, ratio=ratio, mutual=mutual, f_method=f_method,
                    threshold_px=threshold_px, **params)
    if result.num < min_matches:
        raise MatchingError(
            f"{method}: {result.num} verified matches (need {min_matches})"
            + (f": {result.note}" if result.note else ""))
    return result
