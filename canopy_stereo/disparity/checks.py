"""Sanity checks of a rectified pair and its disparity: swapped cameras, a range too narrow.

* :func:`check_not_swapped`: left and right swapped put every match off its row (verging
  cameras) or at a negative or tiny disparity (parallel ones): the cloud comes out empty,
  or as points kilometres away. Sparse ORB matches of the pair rectified both ways round
  tell which order the rig explains, before anything is matched densely.
* :func:`range_limit_warning`: pixels piling up at the ends of the searched range are
  scene parts nearer (largest disparity) or farther (smallest) than the working distance;
  the matcher clips them there or drops them. One line names the range and how to widen it.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Fewest row-consistent matches for a decision on the order of the cameras.
MIN_MATCHES = 25
#: Largest row difference (pixels) of a match in a rectified pair.
ROW_TOLERANCE_PX = 2.0
#: Share of the valid pixels within one pixel of a range end above which it is reported.
PILE_UP_SHARE = 0.02


def signed_match_disparities(left_gray: np.ndarray, right_gray: np.ndarray) -> np.ndarray:
    """``u_left - u_right`` (pixels) of the ORB matches of a rectified grey pair that lie on
    the same row (within :data:`ROW_TOLERANCE_PX`), mutual best matches only."""
    orb = cv2.ORB_create(nfeatures=800)  # type: ignore[attr-defined]  # (absent from OpenCV 5.0's stubs)
    kl, dl = orb.detectAndCompute(np.ascontiguousarray(left_gray), None)
    kr, dr = orb.detectAndCompute(np.ascontiguousarray(right_gray), None)
    if dl is None or dr is None or len(kl) < 2 or len(kr) < 2:
        return np.zeros(0)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    if not matches:
        return np.zeros(0)
    pl = np.array([kl[m.queryIdx].pt for m in matches])
    pr = np.array([kr[m.trainIdx].pt for m in matches])
    same_row = np.abs(pl[:, 1] - pr[:, 1]) <= ROW_TOLERANCE_PX
    return (pl[:, 0] - pr[:, 0])[same_row]


def _in_range(d: np.ndarray, disp_min: float, disp_max: float) -> np.ndarray:
    return (d >= disp_min - 2.0) & (d <= disp_max + 2.0)


def check_not_swapped(given, swapped, *, disp_min: float, disp_max: float) -> np.ndarray:
    """Raise :class:`CanopyStereoError` with one line when a pair looks swapped; else return
    the row-consistent match disparities of the given order (pixels, for
    :func:`range_limit_warning`).

    ``given``: the rectified grey pair ``(left, right)`` as the user gave the images;
    ``swapped``: the pair rectified with the images exchanged. The pair is refused when
    the exchanged order explains the matches much better (row-consistent matches inside
    ``[disp_min, disp_max]``, two pixels of slack) than the given one: a swapped pair's
    matches lie off their rows (verging cameras) or behind the cameras or beyond the
    working distance (parallel cameras). Pairs with too few matches either way pass.
    """
    d_given = signed_match_disparities(*given)
    d_swapped = signed_match_disparities(*swapped)
    s_given = int(_in_range(d_given, disp_min, disp_max).sum())
    s_swapped = int(_in_range(d_swapped, disp_min, disp_max).sum())
    if s_swapped >= MIN_MATCHES and s_swapped > 3 * s_given and s_swapped > 0.5 * len(d_given):
        raise CanopyStereoError(
            f"the left and right images are swapped: exchanged, {s_swapped} matches fit the rig "
            f"(same rows, disparities {disp_min}..{disp_max} px), as given only {s_given}; "
            "give the left camera's image first")
    return d_given


def range_limit_warning(disparity: np.ndarray, disp_min: int, disp_max: int, *, matches=None,
                        focal_px: float | None = None, baseline_m: float | None = None) -> str | None:
    """One line when the scene reaches beyond the searched range ``[disp_min, disp_max]``
    (pixels), naming the range (and its depths when ``focal_px``/``baseline_m`` are given)
    and how to widen it; None otherwise.

    Two signs: more than :data:`PILE_UP_SHARE` of the valid pixels of ``disparity``
    (invalid < 0 or NaN) within one pixel of an end of the range (the matcher clipped them
    there), or of the sparse row-consistent ``matches`` (their disparities, e.g. from
    :func:`check_not_swapped`; a matcher with a left-right check drops what lies beyond
    its range instead of clipping it) beyond an end.
    """
    d = np.asarray(disparity, np.float64)
    v = d[np.isfinite(d) & (d >= 0)]
    m = np.zeros(0) if matches is None else np.asarray(matches, np.float64)
    m = m[np.isfinite(m) & (m > 0)] if len(m) >= MIN_MATCHES else np.zeros(0)

    def share(pixels, sparse):
        return max(float(np.mean(pixels)) if pixels.size else 0.0, float(np.mean(sparse)) if sparse.size else 0.0)

    near = share(v >= disp_max - 1.0, m > disp_max + 2.0)
    far = share(v <= disp_min + 1.0, m < disp_min - 2.0) if disp_min > 0 else 0.0

    def depth(px):
        if not focal_px or not baseline_m or px <= 0:
            return ""
        return f" = {focal_px * baseline_m / px:.2f} m"

    if near > PILE_UP_SHARE:
        seen = f", matched up to {m.max():.0f} px{depth(m.max())}" if m.size and m.max() > disp_max + 2.0 else ""
        return (f"{near * 100:.1f} % of the matched pixels lie at or beyond the largest disparity searched "
                f"({disp_max} px{depth(disp_max)}{seen}): part of the scene is nearer than the working distance "
                "and is missing; widen it with --near M (rig key near_m) or a larger --disp-max")
    if far > PILE_UP_SHARE:
        return (f"{far * 100:.1f} % of the matched pixels lie at or below the smallest disparity searched "
                f"({disp_min} px{depth(disp_min)}): part of the scene is farther than the working distance "
                "and is missing; widen it with --far M (rig key far_m) or a smaller --disp-min")
    return None
