"""The camera that produced an organized cloud, recovered from the cloud itself.

Every point of an organized cloud was triangulated from (or rendered at) its
own left-image pixel, so the pairs ``(X, (u, v))`` are 2D-3D correspondences
of the left camera and a DLT fit recovers its ``P`` when the scene has depth
(a single plane does not determine it). Measurements use the camera to smooth
a leaf along its viewing rays, where a stereo reconstruction errs.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.calibration import dlt_projection, reprojection_errors
from canopy_stereo.geometry.camera import validate_projection

#: Largest RMS reprojection error (pixels) of an accepted camera estimate.
MAX_REPROJECTION_RMS = 0.5


def estimate_camera(organized: np.ndarray, max_points: int = 600, *, seed: int = 0) -> np.ndarray | None:
    """Left camera ``P`` (3, 4) of an organized cloud, or None if it cannot be told.

    Uses up to ``max_points`` finite points spread over the grid; fails (None)
    with fewer than 12 points, coplanar points, or an RMS reprojection error
    above :data:`MAX_REPROJECTION_RMS` pixels.
    """
    organized = np.asarray(organized, np.float64)
    finite = np.all(np.isfinite(organized), axis=-1)
    vs, us = np.nonzero(finite)
    if len(vs) < 12:
        return None
    if len(vs) > max_points:
        pick = np.random.default_rng(seed).choice(len(vs), max_points, replace=False)
        vs, us = vs[pick], us[pick]
    X = organized[vs, us]
    x = np.stack([us, vs], axis=1).astype(np.float64)
    try:
        P = dlt_projection(X, x)
    except (CanopyStereoError, np.linalg.LinAlgError):
        return None
    err = reprojection_errors(P, X, x)
    if not np.all(np.isfinite(err)) or np.sqrt(np.mean(err ** 2)) > MAX_REPROJECTION_RMS:
        return None
    return P


def resolve_camera(camera, organized: np.ndarray) -> np.ndarray | None:
    """``camera`` as a validated (3, 4) array; ``"auto"`` estimates it; None stays None."""
    if camera is None:
        return None
    if isinstance(camera, str):
        if camera != "auto":
            raise CanopyStereoError(f"camera must be a 3x4 matrix, 'auto' or None, got {camera!r}")
        return estimate_camera(organized)
    return validate_projection(camera, "camera")
