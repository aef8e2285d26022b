"""Two images -> metric point cloud (the paper's Figure 13).

Stages: rectify (:func:`rectify_rig`: the rig's method, Fusiello from its P matrices or
Hartley from its stored homographies or from matches), dense
disparity on the rectified pair, back-mapping of the matches to the original
images and triangulation with the world-frame ``P`` matrices, optionally
restricted to a foreground mask drawn on the original left image.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.disparity import DEFAULT_MATCHER, compute_disparity
from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.geometry.distortion import undistort_pixels
from canopy_stereo.geometry.rectification import (
    Rectification,
    cached_rectifier,
    default_disparity_range,
)
from canopy_stereo.geometry.rig_rectification import (  # noqa: F401 - RECTIFICATION_METHODS re-exported
    RECTIFICATION_METHODS,
    rectification_for_rig,
    rig_rectification_method,
    stored_homographies,
)
from canopy_stereo.geometry.triangulation import organized_from_disparity
from canopy_stereo.io.images import check_pair, to_bgr, to_gray


@dataclass
class Reconstruction:
    """Result of :func:`reconstruct_pair`.

    Attributes:
        points: (N, 3) float64 world points (rig units) of the valid pixels.
        colors: (N, 3) uint8 RGB colours of those points (from the left image).
        pixels: (N, 2) int (u, v) original left pixel of each point.
        organized: (H, W, 3) world points on the original left pixel grid, NaN where none.
        disparity: (Hr, Wr) float32 rectified left disparity, invalid < 0.
        rectification: the :class:`Rectification` used.
        rectified: ``(left, right)`` rectified BGR images.
        disp_range: ``(disp_min, disp_max)`` searched, pixels.
        timings: stage name -> seconds.
        warnings: one line each, things the user should know (the range too narrow, ...).
    """

    points: np.ndarray
    colors: np.ndarray
    pixels: np.ndarray
    organized: np.ndarray
    disparity: np.ndarray
    rectification: Rectification
    rectified: tuple
    disp_range: tuple[int, int]
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)

    def bounding_box(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) of the points, world units."""
        if len(self.points) == 0:
            return np.full(3, np.nan), np.full(3, np.nan)
        return self.points.min(axis=0), self.points.max(axis=0)


def rectify_rig(rig, method: str | None = None, *, left=None, right=None, match_method: str = "qdmatch",
                match_pairs=(), from_matches: bool | None = None) -> Rectification:
    """Rectification for ``rig``
    (:func:`~canopy_stereo.geometry.rig_rectification.rectification_for_rig`).

    ``method`` None = the rig's (its ``method`` extra parameter, else ``fusiello``).
    ``fusiello``: from the rig's P matrices. ``hartley``: the rig's stored homographies
    (``H_left``/``H_right``, written by ``canopy-stereo rectify --method hartley``), or,
    when the rig has none, when ``match_pairs`` are given or when ``from_matches`` is
    True, homographies estimated from F on matches (``match_method``, quasi-dense by
    default) found in the raw ``left``/``right`` images plus any further ``match_pairs``
    taken by the same fixed rig (pooling pairs spreads the matches over the whole field
    of view, which a single planar or repetitive scene does not); matches are
    undistorted with the rig's D before F is estimated.
    """
    chosen = rig_rectification_method(rig, method)
    if from_matches is None:
        from_matches = bool(match_pairs) or not stored_homographies(rig)
    if chosen != "hartley" or not from_matches:
        return rectification_for_rig(rig, method=chosen)
    pairs = ([(left, right)] if left is not None and right is not None else []) + list(match_pairs)
    if not pairs:
        raise CanopyStereoError("Hartley rectification needs images to find matches")
    from canopy_stereo.features import match_pair

    xl, xr = [], []
    for a, b in pairs:
        m = match_pair(a, b, method=match_method, min_matches=0)
        xl.append(undistort_pixels(rig.P_left, rig.D_left, m.x_left, model=rig.distortion_model))
        xr.append(undistort_pixels(rig.P_right, rig.D_right, m.x_right, model=rig.distortion_model))
    return rectification_for_rig(rig, method="hartley", matches=(np.vstack(xl), np.vstack(xr)))


def _whole_pixels(value, name: str) -> int:
    """``value`` as an int number of pixels, or :class:`CanopyStereoError` naming ``name``."""
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise CanopyStereoError(f"{name} must be a whole number of pixels, got {value!r}") from None
    if not np.isfinite(f) or f != int(f):
        raise CanopyStereoError(f"{name} must be a whole number of pixels, got {value!r}")
    return int(f)


def _metres(value, name: str) -> float | None:
    if value is None:
        return None
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise CanopyStereoError(f"{name} must be a distance in metres, got {value!r}") from None
    if not np.isfinite(f) or f <= 0:
        raise CanopyStereoError(f"{name} must be a positive distance in metres, got {value!r}")
    return f


def working_distance_range(rect: Rectification, *, near_m=None, far_m=None,
                           metres_per_unit: float = 1e-3) -> tuple[int, int]:
    """Disparity range (pixels, one pixel of margin each side) of a working distance:
    depths along the rectified optical axis from ``near_m`` (None = 8 baselines) to
    ``far_m`` (None = infinity) metres, for a metric (Fusiello) rectification whose
    baseline is in world units of ``metres_per_unit`` metres."""
    from canopy_stereo.geometry.rectification import metric_disparity_range

    near, far = _metres(near_m, "near_m"), _metres(far_m, "far_m")
    if rect.method != "fusiello":
        raise CanopyStereoError("a working distance (near_m/far_m) needs a metric (fusiello) rectification; "
                                "give disp_min/disp_max in pixels instead")
    if near is not None and far is not None and far <= near:
        raise CanopyStereoError(f"far_m ({far:g} m) must be greater than near_m ({near:g} m)")
    k = 1.0 / metres_per_unit  # metres -> world units of the baseline
    return metric_disparity_range(rect.focal_length, rect.baseline, doffs=rect.doffs,
                                  near_depth=None if near is None else near * k,
                                  far_depth=None if far is None else far * k)


def disparity_range_for(rig, rect: Rectification, *, disp_min=None, disp_max=None, near_m=None,
                        far_m=None) -> tuple[int, int]:
    """Search range (pixels), first found wins: explicit ``disp_min``/``disp_max``, an
    explicit working distance ``near_m``/``far_m`` (metres, :func:`working_distance_range`),
    the rig file's ``disp_min``/``disp_max``, the rig file's ``near_m``/``far_m``, then
    :func:`default_disparity_range` (depths beyond 8 baselines).

    The one check of a disparity range (``reconstruct``, ``run`` and ``disparity_node``):
    whole pixels, ``0 <= disp_min < disp_max``; else :class:`CanopyStereoError`.

    This is the one place where a rig file's range meets a rectification. The values
    are disparities ``u_left - u_right`` of the rectified pair; with the package's
    Fusiello rectification (one principal point for both cameras, ``doffs = 0``)
    they are ``f B / Z``, the same numbers as a ``stereo_msgs/DisparityImage``'s
    ``min_disparity``/``max_disparity``. (Rig files written before the common
    principal point, for a rectification with ``doffs > 0``, need their range
    lowered by that ``doffs``; the bundled ``config/croton_rig.yaml`` was.)
    """
    dmin, dmax = default_disparity_range(rect)
    if near_m is not None or far_m is not None:
        dmin, dmax = working_distance_range(rect, near_m=near_m, far_m=far_m, metres_per_unit=rig.metres_per_unit)
    else:
        if rig.extra.get("near_m") is not None or rig.extra.get("far_m") is not None:
            dmin, dmax = working_distance_range(rect, near_m=rig.extra.get("near_m"), far_m=rig.extra.get("far_m"),
                                                metres_per_unit=rig.metres_per_unit)
        dmin = rig.extra.get("disp_min", dmin)
        dmax = rig.extra.get("disp_max", dmax)
    dmin = _whole_pixels(dmin if disp_min is None else disp_min, "disp_min")
    dmax = _whole_pixels(dmax if disp_max is None else disp_max, "disp_max")
    if dmin < 0:
        raise CanopyStereoError(f"disp_min must be >= 0 pixels, got {dmin} (a negative disparity "
                                "puts the point behind the cameras)")
    if dmax <= dmin:
        raise CanopyStereoError(f"disp_max ({dmax}) must be greater than disp_min ({dmin})")
    return dmin, dmax


def rig_matcher_params(rig, matcher: str, *, given=None) -> dict:
    """Matcher parameters for ``matcher``: the rig file's ``<matcher>: {name: value}`` entry
    (e.g. ``elas: {subpixel: true}``, as ``disparity_node`` reads it from the same file as
    ``elas.subpixel``) updated with the ``given`` ones."""
    from_rig = rig.extra.get(matcher) if hasattr(rig, "extra") else None
    return {**(from_rig if isinstance(from_rig, dict) else {}), **(given or {})}


def reconstruct_pair(left_bgr, right_bgr, rig, *, method: str | None = None, matcher: str = DEFAULT_MATCHER,
                     mask=None, disp_min=None, disp_max=None, near_m=None, far_m=None, matcher_params=None,
                     rectification: Rectification | None = None, check_order: bool = True) -> Reconstruction:
    """Reconstruct one stereo pair into world coordinates.

    Args:
        left_bgr, right_bgr: original (raw) images, uint8 grey or BGR, of the rig's size.
        rig: :class:`~canopy_stereo.io.rig.Rig` with world-frame P matrices.
        method: ``"fusiello"`` (calibrated) or ``"hartley"`` (projective: the rig's stored
            homographies, else from matches); None = the rig's method (:func:`rectify_rig`).
        matcher: disparity matcher name (``"elas"``, the paper's, or ``"sgbm"``).
        mask: optional (H, W) foreground mask on the original left image (non-zero = keep).
        disp_min, disp_max: disparity search range in rectified pixels (default: from
            the working distance or the rig file, :func:`disparity_range_for`).
        near_m, far_m: working distance (metres along the optical axis) the range covers.
        matcher_params: extra keyword arguments for the matcher (over the rig file's
            ``<matcher>: {...}`` parameters, which ``disparity_node`` reads too).
        rectification: reuse a precomputed rectification (skips that stage).
        check_order: refuse a swapped pair (:func:`~canopy_stereo.disparity.checks.check_not_swapped`,
            :class:`CanopyStereoError`).

    Returns:
        A :class:`Reconstruction` in the rig's world units; its ``warnings`` name pixels
        piling up at the ends of the searched range
        (:func:`~canopy_stereo.disparity.checks.range_limit_warning`).
    """
    timings: dict[str, float] = {}
    left, right = to_bgr(left_bgr, "left"), to_bgr(right_bgr, "right")
    check_pair(left, right, expected_size=rig.image_size)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape[:2] != left.shape[:2]:
            raise ImageError(f"mask is {mask.shape[1]}x{mask.shape[0]} but the images are "
                             f"{left.shape[1]}x{left.shape[0]}")
        if mask.ndim == 3:
            mask = mask.max(axis=2)
        if not np.any(mask):
            raise ImageError("mask is empty: no foreground pixel to reconstruct")

    t = time.perf_counter()
    rect = rectification or rectify_rig(rig, method, left=left, right=right)
    timings["rectification"] = time.perf_counter() - t

    t = time.perf_counter()
    rectifier = cached_rectifier(rig, rect)
    left_r, right_r = rectifier.rectify(left, right)
    # the matcher's right image as rectify_node makes it: grey first, then one remap (the grey of
    # the rectified colour image differs by rounding, and ELAS would see a different pair)
    right_grey_r = rectifier.rectify_one(to_gray(right), "right")
    timings["warp"] = time.perf_counter() - t

    dmin, dmax = disparity_range_for(rig, rect, disp_min=disp_min, disp_max=disp_max, near_m=near_m, far_m=far_m)
    matches = None
    if check_order:
        from canopy_stereo.disparity.checks import check_not_swapped

        t = time.perf_counter()
        swapped = cached_rectifier(rig, rect).rectify(right, left)
        matches = check_not_swapped((to_gray(left_r), to_gray(right_r)),
                                    (to_gray(swapped[0]), to_gray(swapped[1])), disp_min=dmin, disp_max=dmax)
        timings["order check"] = time.perf_counter() - t

    t = time.perf_counter()
    disp = compute_disparity(to_gray(left_r), right_grey_r, matcher=matcher, disp_min=dmin,
                             disp_max=dmax, **rig_matcher_params(rig, matcher, given=matcher_params))
    timings["disparity"] = time.perf_counter() - t
    from canopy_stereo.disparity.checks import range_limit_warning

    metric = rect.method == "fusiello"
    warning = range_limit_warning(disp, dmin, dmax, matches=matches, focal_px=rect.focal_length if metric else None,
                                  baseline_m=rect.baseline * rig.metres_per_unit if metric else None)

    t = time.perf_counter()
    organized = organized_from_disparity(disp, rect, rig.P_left, rig.P_right, rig.image_size,
                                         D_left=rig.D_left, distortion_model=rig.distortion_model)
    if mask is not None:
        organized[mask == 0] = np.nan
    timings["triangulation"] = time.perf_counter() - t

    valid = np.all(np.isfinite(organized), axis=2)
    vv, uu = np.nonzero(valid)
    points = organized[vv, uu]
    colors = left[vv, uu][:, ::-1].copy()
    return Reconstruction(points=points, colors=colors, pixels=np.stack([uu, vv], axis=1),
                          organized=organized, disparity=disp, rectification=rect,
                          rectified=(left_r, right_r), disp_range=(dmin, dmax), timings=timings,
                          warnings=[warning] if warning else [])
