"""Coverage and accuracy of a reconstructed model against true surface samples.

* Coverage (completeness): the share of true surface samples that have a
  model point within ``radius``; samples should be spread evenly over the true
  surface (e.g. :func:`canopy_stereo.sim.multiview.sample_leaf_surfaces`), so the
  share estimates the share of the surface area covered.
* Accuracy: distances from each model point to the nearest true sample
  (median, 90th percentile, RMS), i.e. how far the model lies from the truth.
  When the truth covers only part of the scene (the leaves, not the pot),
  ``max_distance`` restricts this to the model points within that distance of
  the truth (the points that belong to the sampled surface); note that the
  distance to the nearest *sample* includes up to half the sample spacing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from canopy_stereo.errors import CanopyStereoError


def _points(a) -> np.ndarray:
    pts = np.asarray(a, np.float64).reshape(-1, 3)
    return pts[np.all(np.isfinite(pts), axis=1)]


def covered_mask(model_points, truth_points, radius: float) -> np.ndarray:
    """(N_truth,) bool: truth samples with a model point within ``radius`` (world units)."""
    truth = np.asarray(truth_points, np.float64).reshape(-1, 3)
    model = _points(model_points)
    if len(model) == 0:
        return np.zeros(len(truth), bool)
    d, _ = cKDTree(model).query(truth, k=1, distance_upper_bound=radius)
    return np.isfinite(d)


def surface_coverage(model_points, truth_points, radius: float) -> float:
    """Share in [0, 1] of the true surface samples covered by the model within ``radius``."""
    truth = _points(truth_points)
    if len(truth) == 0:
        raise CanopyStereoError("no true surface samples to measure coverage against")
    return float(covered_mask(model_points, truth, radius).mean())


@dataclass
class CoverageReport:
    """Coverage and accuracy figures of one model (lengths in world units)."""

    coverage: float
    radius: float
    median_error: float
    p90_error: float
    rms_error: float
    model_points: int
    evaluated_points: int

    def to_dict(self) -> dict:
        return {"coverage": self.coverage, "radius": self.radius, "median_error": self.median_error,
                "p90_error": self.p90_error, "rms_error": self.rms_error, "model_points": self.model_points,
                "evaluated_points": self.evaluated_points}


def evaluate_model(model_points, truth_points, radius: float, *,
                   max_distance: float | None = None) -> CoverageReport:
    """Coverage of ``truth_points`` by the model and the model's distance to the truth.

    ``max_distance``: judge accuracy only on model points within this distance
    of the truth (default: all model points).
    """
    truth = _points(truth_points)
    model = _points(model_points)
    if len(truth) == 0:
        raise CanopyStereoError("no true surface samples to measure coverage against")
    cov = surface_coverage(model, truth, radius)
    d = cKDTree(truth).query(model, k=1)[0] if len(model) else np.zeros(0)
    if max_distance is not None:
        d = d[d <= max_distance]
    if len(d) == 0:
        return CoverageReport(cov, float(radius), float("nan"), float("nan"), float("nan"), int(len(model)), 0)
    return CoverageReport(coverage=cov, radius=float(radius), median_error=float(np.median(d)),
                          p90_error=float(np.percentile(d, 90)), rms_error=float(np.sqrt(np.mean(d ** 2))),
                          model_points=int(len(model)), evaluated_points=int(len(d)))
