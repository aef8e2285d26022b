"""The common end of every calibration importer: two cameras + their extrinsics -> a rig.

Each format's reader (one module per format in this package) finds, in its tool's own
conventions, each camera's intrinsics ``K``, lens distortion ``D`` (and model), image size,
and the rigid transform from the left camera to the right one (``X_right = R X_left + T``,
``T`` in the file's unit). :func:`rig_from_cameras` checks them (one
:class:`~canopy_stereo.errors.CalibrationError` line naming the file and field) and builds
the :class:`~canopy_stereo.geometry.rig.Rig` whose world frame is the left camera's
optical frame: ``P_left = K_left [I | 0]``, ``P_right = K_right [R | T]``.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CalibrationError, RigError
from canopy_stereo.geometry.distortion import check_distortion, distortion_is_identity
from canopy_stereo.geometry.rig import Rig, unit_to_metres

#: Largest deviation of ``R^T R`` from the identity accepted as a rotation (files round to
#: 6-8 decimals); the imported rotation is the nearest exact one.
ROTATION_TOLERANCE = 1e-4


@dataclass(frozen=True)
class CameraIntrinsics:
    """One camera as a calibration file describes it.

    Attributes:
        K: (3, 3) intrinsics of the raw image (pixels).
        D: distortion coefficients of ``model`` (REP 104 name; see
            :mod:`canopy_stereo.geometry.distortion`).
        model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
        size: ``(width, height)`` of the raw image (pixels).
    """

    K: np.ndarray
    D: np.ndarray
    model: str
    size: tuple[int, int]


def unknown_field(source: str, name: str, known) -> CalibrationError:
    """The error of an unexpected field ``name``, suggesting the nearest known name."""
    close = difflib.get_close_matches(str(name), list(known), n=1, cutoff=0.75)
    hint = f" (did you mean {close[0]!r}?)" if close else f" (expected: {', '.join(sorted(known))})"
    return CalibrationError(f"{source}: unknown field {name!r}{hint}")


def matrix(value, shape, source: str, name: str) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape``, else one error line naming it."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: {name} must be numbers, got {value!r}") from None
    n = int(np.prod(shape))
    if a.size != n:
        raise CalibrationError(f"{source}: {name} must have {n} numbers ({'x'.join(map(str, shape))}), got {a.size}")
    if not np.all(np.isfinite(a)):
        raise CalibrationError(f"{source}: {name} has non-finite entries")
    return a.reshape(shape)


def intrinsics(K, source: str, name: str) -> np.ndarray:
    """A checked (3, 3) camera matrix: upper triangular, positive focal lengths, ``K[2, 2] = 1``."""
    K = matrix(K, (3, 3), source, name)
    if abs(K[2, 2] - 1) > 1e-9 or np.any(np.abs(K[[1, 2, 2], [0, 0, 1]]) > 1e-9):
        raise CalibrationError(f"{source}: {name} is not a camera matrix [fx s cx; 0 fy cy; 0 0 1]")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationError(f"{source}: {name} has non-positive focal lengths")
    return K


def rotation(R, source: str, name: str) -> np.ndarray:
    """The nearest exact rotation to ``R`` (3x3), which must be one to
    :data:`ROTATION_TOLERANCE`; else one error line naming it."""
    R = matrix(R, (3, 3), source, name)
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ROTATION_TOLERANCE or np.linalg.det(R) <= 0:
        raise CalibrationError(f"{source}: {name} is not a rotation (|R^T R - I| = {err:.2g}, "
                               f"det = {np.linalg.det(R):.4g})")
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def distortion(D, model: str | None, source: str, name: str) -> np.ndarray:
    """``D`` checked for ``model`` (:func:`canopy_stereo.geometry.distortion.check_distortion`)."""
    try:
        return check_distortion(D, model, f"{source}: {name}")
    except RigError as exc:
        raise CalibrationError(str(exc)) from None


def image_size(width, height, source: str) -> tuple[int, int]:
    """``(width, height)`` as positive whole numbers of pixels."""
    try:
        w, h = float(width), float(height)
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: image size must be numbers, got {width!r} x {height!r}") from None
    if not (w == int(w) and h == int(h) and w > 0 and h > 0):
        raise CalibrationError(f"{source}: image size must be positive whole pixels, got {width} x {height}")
    return int(w), int(h)


def rig_from_cameras(left: CameraIntrinsics, right: CameraIntrinsics, R, T, *, unit: str,
                     source: str, extra: dict | None = None) -> Rig:
    """The rig of two cameras, world frame = the left camera's optical frame.

    Args:
        left, right: the cameras (:class:`CameraIntrinsics`).
        R, T: left -> right camera transform, ``X_right = R X_left + T``; ``T`` in ``unit``.
        unit: the translations' unit (``m``, ``mm``, ...), recorded as the rig's world unit.
        source: names the input in errors.
        extra: more rig parameters (e.g. a Middlebury disparity range).

    Raises :class:`CalibrationError` for differing image sizes or distortion models, a
    ``R`` that is not a rotation, a zero baseline or an unknown unit.
    """
    try:
        unit_to_metres(unit)
    except RigError as exc:
        raise CalibrationError(f"{source}: {exc}") from None
    if left.size != right.size:
        raise CalibrationError(f"{source}: the image sizes differ (left {left.size[0]}x{left.size[1]}, "
                               f"right {right.size[0]}x{right.size[1]}); a rig has one image size")
    if left.model != right.model and "equidistant" in (left.model, right.model):
        raise CalibrationError(f"{source}: the cameras use different lens models ({left.model}, "
                               f"{right.model}); a rig has one")
    R = rotation(R, source, "R")
    T = matrix(T, (3,), source, "T")
    if not np.linalg.norm(T) > 0:
        raise CalibrationError(f"{source}: the baseline T is zero")
    P_left = left.K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = right.K @ np.hstack([R, T.reshape(3, 1)])
    model = "equidistant" if left.model == "equidistant" else None
    # a zero distortion written in another form (k1..k3 == k4..k6, as our camera infos do) is zeros
    Dl, Dr = (np.zeros(5) if model is None and distortion_is_identity(c.D, model=c.model) else c.D
              for c in (left, right))
    if model is None and Dl.size != Dr.size:  # one OpenCV coefficient vector length for both
        n = max(Dl.size, Dr.size, 5)
        Dl, Dr = (np.concatenate([d, np.zeros(n - d.size)]) for d in (Dl, Dr))
    try:
        return Rig(P_left=P_left, P_right=P_right, image_size=left.size, world_unit=unit, D_left=Dl,
                   D_right=Dr, distortion_model=model, extra=dict(extra or {}))
    except RigError as exc:
        raise CalibrationError(f"{source}: {exc}") from None
