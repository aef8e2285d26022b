"""Lens distortion: OpenCV's models (REP 104 names) on pixels of a projection matrix.

Models (``distortion_model`` of a ``sensor_msgs/CameraInfo``):

* ``plumb_bob`` / ``rational_polynomial``: OpenCV's standard model, coefficients in
  OpenCV's order ``[k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]]`` (4, 5, 8 or 12
  numbers; 14 with the tilt terms ``tau_x, tau_y`` zero). The radial factor is
  ``(1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``, plus tangential
  (``p1, p2``) and thin-prism (``s1..s4``) terms. ``plumb_bob`` is the name for up to 5
  coefficients, ``rational_polynomial`` for 8 or more; both are the same formula.
* ``equidistant``: OpenCV's fisheye model (``cv2.fisheye``, Kalibr's ``equidistant``,
  ROS's ``equidistant``), ``[k1, k2, k3, k4]``: a ray at angle ``theta`` from the optical
  axis lands at normalised radius ``theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 +
  k4 theta^8)``.

Pixels are mapped through the full intrinsics ``K`` of a projection matrix (including
skew), so "ideal" pixels are exactly those a pinhole ``P`` predicts. ``model=None`` means
the OpenCV standard model (:func:`default_distortion_model` of ``D``'s length).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.camera import decompose_projection

#: Distortion models (REP 104 names) the package computes with.
DISTORTION_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
#: Coefficient counts each model accepts.
MODEL_SIZES = {"plumb_bob": (4, 5), "rational_polynomial": (8, 12, 14), "equidistant": (4,)}

_CONVERGED = 1e-13  # normalised coordinates


def default_distortion_model(D) -> str:
    """``plumb_bob`` for up to 5 OpenCV coefficients, ``rational_polynomial`` for more."""
    n = 0 if D is None else np.asarray(D).size
    return "plumb_bob" if n <= 5 else "rational_polynomial"


def check_distortion(D, model: str | None, name: str) -> np.ndarray:
    """``D`` as float64 coefficients valid for ``model`` (None = by length); raises
    :class:`~canopy_stereo.errors.RigError` naming ``name`` otherwise (wrong count for the
    model, non-finite, unknown model, non-zero tilt terms, which no tool here uses)."""
    model = model or default_distortion_model(D)
    if model not in DISTORTION_MODELS:
        raise RigError(f"{name}: unknown distortion model {model!r}; expected one of {', '.join(DISTORTION_MODELS)}")
    try:
        d = np.zeros(0) if D is None else np.asarray(D, dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise RigError(f"{name} must be a list of numbers") from None
    sizes = MODEL_SIZES[model] if model == "equidistant" else (0, 4, 5, 8, 12, 14)
    if d.size not in sizes:
        raise RigError(f"{name} must have {', '.join(map(str, sizes[1:] if sizes[0] == 0 else sizes))} "
                       f"coefficients for the {model} model, got {d.size}")
    if not np.all(np.isfinite(d)):
        raise RigError(f"{name} has non-finite entries")
    if d.size == 14 and np.any(d[12:]):
        raise RigError(f"{name}: the tilted-sensor terms (coefficients 13-14) must be zero")
    return d


def _opencv_terms(D):
    d = np.zeros(12)
    D = np.asarray(D, np.float64).ravel()[:12]
    d[:D.size] = D
    return d


def distort_normalised(x, y, D, *, model: str | None = None):
    """Ideal normalised coordinates ``(x, y)`` (arrays, ``X/Z, Y/Z``) -> distorted ones."""
    if (model or default_distortion_model(D)) == "equidistant":
        k = np.zeros(4)
        k[:len(D)] = D
        r = np.hypot(x, y)
        theta = np.arctan(r)
        t2 = theta * theta
        theta_d = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(r > 1e-12, theta_d / r, 1.0)
        return x * scale, y * scale
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _opencv_terms(D)
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + r2 * s2)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + r2 * s4)
    return xd, yd


def undistort_normalised(xd, yd, D, *, model: str | None = None, iterations: int = 100):
    """Distorted normalised coordinates -> ideal ones: inverse of :func:`distort_normalised`.

    OpenCV standard model: fixed-point iteration as OpenCV's ``undistortPoints`` until the
    step is below 1e-13 (at most ``iterations``). Equidistant: Newton on ``theta`` as
    ``cv2.fisheye.undistortPoints``; radii beyond 90 degrees give NaN.
    """
    xd = np.asarray(xd, np.float64)
    yd = np.asarray(yd, np.float64)
    if (model or default_distortion_model(D)) == "equidistant":
        k = np.zeros(4)
        k[:len(D)] = D
        theta_d = np.hypot(xd, yd)
        theta = theta_d.copy()
        for _ in range(iterations):
            t2 = theta * theta
            f = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - theta_d
            df = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
            step = f / df
            theta = theta - step
            if not np.any(np.abs(step) > _CONVERGED):
                break
        ok = (theta >= 0) & (theta < np.pi / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(theta_d > 1e-12, np.tan(theta) / theta_d, 1.0)
        scale = np.where(ok, scale, np.nan)
        return xd * scale, yd * scale
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = _opencv_terms(D)
    x, y = xd.copy(), yd.copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        icdist = (1 + r2 * (k4 + r2 * (k5 + r2 * k6))) / (1 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + r2 * s2)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + r2 * s4)
        xn = (xd - dx) * icdist
        yn = (yd - dy) * icdist
        step = np.maximum(np.abs(xn - x), np.abs(yn - y))
        x, y = xn, yn
        if not np.any(step > _CONVERGED):
            break
    return x, y


def distortion_is_identity(D, *, model: str | None = None) -> bool:
    """True when ``D`` of ``model`` moves no pixel: None, all zeros, or OpenCV's rational
    model with ``k1..k3 == k4..k6`` and no other term (the zero-distortion form
    :func:`canopy_stereo.geometry.frames.camera_info_distortion` publishes)."""
    if D is None:
        return True
    d = np.asarray(D, np.float64).ravel()
    if not np.any(d):
        return True
    # k1..k3 == k4..k6 and nothing else: the radial ratio is exactly 1 (the zero-distortion
    # representation image_proc rectifies, see canopy_stereo.geometry.frames)
    return ((model or default_distortion_model(d)) != "equidistant" and d.size >= 8
            and not np.any(d[2:4]) and np.array_equal(d[[0, 1, 4]], d[5:8]) and not np.any(d[8:]))


def distort_pixels(P, D, xy, *, model: str | None = None) -> np.ndarray:
    """Ideal (pinhole) pixels (N, 2) -> distorted pixels.

    Uses the full intrinsics ``K`` of ``P`` (3, 4) (including skew) and the coefficients
    ``D`` of ``model`` (see the module docstring; None = OpenCV's standard model).
    """
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if distortion_is_identity(D, model=model):
        return xy
    K = decompose_projection(P).K
    n = np.linalg.solve(K, np.column_stack([xy, np.ones(len(xy))]).T)
    xd, yd = distort_normalised(n[0] / n[2], n[1] / n[2], np.asarray(D, np.float64).ravel(), model=model)
    out = K @ np.vstack([xd, yd, np.ones_like(xd)])
    return (out[:2] / out[2]).T


def undistort_pixels(P, D, xy, *, model: str | None = None, iterations: int = 100) -> np.ndarray:
    """Distorted pixels (N, 2) -> ideal pixels: inverse of :func:`distort_pixels`,
    accurate to well below 1e-6 px for webcam and fisheye lenses (NaN where the lens model
    has no inverse, e.g. beyond 90 degrees for ``equidistant``)."""
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    if distortion_is_identity(D, model=model):
        return xy
    K = decompose_projection(P).K
    n = np.linalg.solve(K, np.column_stack([xy, np.ones(len(xy))]).T)
    x, y = undistort_normalised(n[0] / n[2], n[1] / n[2], np.asarray(D, np.float64).ravel(),
                                model=model, iterations=iterations)
    out = K @ np.vstack([x, y, np.ones_like(x)])
    return (out[:2] / out[2]).T
