"""Disparity evaluation against ground truth (Middlebury-style error statistics).

Conventions: an estimate is *valid* where it is finite and >= 0 (matchers write -1,
PFM files ``inf`` for no value); ground truth is *known* where it is finite (the
readers in :mod:`canopy_stereo.io.middlebury` give NaN for unknown). Errors are
absolute disparity differences in pixels.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from canopy_stereo.errors import CanopyStereoError

#: Thresholds (pixels) of the ``bad>t`` statistics.
BAD_THRESHOLDS = (0.5, 1.0, 2.0, 4.0)


@dataclass(frozen=True)
class DisparityScores:
    """Error statistics of one disparity map, percentages in 0..100.

    Attributes:
        bad: threshold -> share of *evaluated* pixels (ground truth known, estimate
            valid, inside the mask) whose error exceeds the threshold.
        density: share of the pixels inside the mask (all pixels without a mask)
            that have a valid estimate.
        epe: mean absolute error (end-point error) over the evaluated pixels, pixels.
        bad2_all: share of the pixels with known ground truth (inside the mask)
            that are wrong by more than 2 px *or* have no estimate.
        evaluated: number of evaluated pixels.
        known: number of pixels with known ground truth inside the mask.
    """

    bad: dict
    density: float
    epe: float
    bad2_all: float
    evaluated: int
    known: int

    def as_dict(self) -> dict:
        out = asdict(self)
        out["bad"] = {f"{t:g}": v for t, v in self.bad.items()}
        return out

    def format(self) -> str:
        """One-line summary, e.g. ``bad>0.5 12.3%  bad>1 ...  density 85.9%  EPE 0.71 px``."""
        bads = "  ".join(f"bad>{t:g} {v:5.2f}%" for t, v in self.bad.items())
        return (f"{bads}  density {self.density:6.2f}%  EPE {self.epe:.3f} px  "
                f"bad>2(all) {self.bad2_all:5.2f}%  ({self.evaluated} px evaluated)")


def valid_disparity(disp: np.ndarray) -> np.ndarray:
    """bool mask of valid estimates: finite and >= 0."""
    disp = np.asarray(disp)
    with np.errstate(invalid="ignore"):
        return np.isfinite(disp) & (disp >= 0)


def evaluate_disparity(disp: np.ndarray, gt: np.ndarray, *, mask: np.ndarray | None = None,
                       thresholds=BAD_THRESHOLDS) -> DisparityScores:
    """Score an estimated disparity map against ground truth.

    Args:
        disp: estimated disparity (H, W), pixels; invalid = negative or non-finite.
        gt: ground-truth disparity (H, W), pixels; unknown = non-finite.
        mask: optional bool (H, W), True where pixels count (e.g. non-occluded).
        thresholds: error thresholds (pixels) for the ``bad`` statistics.

    Raises:
        CanopyStereoError: if the shapes differ.
    """
    disp = np.asarray(disp, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if disp.ndim != 2 or disp.shape != gt.shape:
        raise CanopyStereoError(
            f"disparity map {disp.shape} and ground truth {gt.shape} must be 2-D and "
            "the same size")
    if mask is None:
        region = np.ones(disp.shape, dtype=bool)
    else:
        region = np.asarray(mask).astype(bool)
        if region.shape != disp.shape:
            raise CanopyStereoError(
                f"mask {region.shape} does not match the disparity map {disp.shape}")
    valid = valid_disparity(disp) & region
    known = np.isfinite(gt) & region
    both = valid & known
    err = np.abs(disp[both] - gt[both])
    n_eval = int(both.sum())
    n_known = int(known.sum())
    n_region = int(region.sum())

    def pct(count, total):
        return 100.0 * count / total if total else float("nan")

    bad = {float(t): pct(int((err > t).sum()), n_eval) for t in thresholds}
    wrong_all = int((err > 2.0).sum()) + int((known & ~valid).sum())
    return DisparityScores(
        bad=bad,
        density=pct(int(valid.sum()), n_region),
        epe=float(err.mean()) if n_eval else float("nan"),
        bad2_all=pct(wrong_all, n_known),
        evaluated=n_eval,
        known=n_known,
    )
