"""Rig -> rectification: the one place that decides how a rig is rectified.

A rig file (:mod:`canopy_stereo.io.rig`) may say how it is rectified in its extra
parameters: ``method`` (``fusiello`` or ``hartley``) and, for Hartley, the two
homographies ``H_left``/``H_right`` (9 numbers each, row-major, original ideal pixel
-> rectified pixel) and the suggested ``disp_min``/``disp_max``, as written by
``canopy-stereo rectify --method hartley``. :func:`rectification_for_rig` reads them;
an explicit ``method`` or explicit homographies override the file's. Every path that
rectifies a rig goes through it: the Python API (:func:`canopy_stereo.pipeline.reconstruct.rectify_rig`,
``reconstruct_pair``), the CLI (``rectify``, ``reconstruct``, ``fuse``, ``run``, ``batch``)
and ``rectify_node`` (from its parameters or its ``rig_file``), so one rig file gives the
same rectification whichever way it is loaded.

Pure numpy; the rig is anything with ``P_left``, ``P_right``, ``image_size`` and
``extra`` (a :class:`~canopy_stereo.io.rig.Rig`).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.rectification import Rectification, fusiello_rectify, hartley_rectify
from canopy_stereo.geometry.triangulation import apply_homography

#: Rectification methods a rig can name (``method`` in its extra parameters).
RECTIFICATION_METHODS = ("fusiello", "hartley")

#: Smallest fraction of the rectified image a raw image must cover through its homography;
#: less means the homographies were computed for another image size (or another rig).
MIN_RECTIFIED_COVERAGE = 0.25


def rig_rectification_method(rig, method: str | None = None) -> str:
    """The rectification method of ``rig``: ``method`` when given (not None/empty), else
    the rig's ``method`` extra parameter, else ``"fusiello"``; raises :class:`RigError`
    for a name not in :data:`RECTIFICATION_METHODS`."""
    chosen = method or rig.extra.get("method") or "fusiello"
    if chosen not in RECTIFICATION_METHODS:
        origin = "" if method else " (the rig's method parameter)"
        raise RigError(f"unknown rectification method {chosen!r}{origin}; choose "
                       f"{' or '.join(RECTIFICATION_METHODS)}")
    return str(chosen)


def stored_homographies(rig) -> bool:
    """True when ``rig``'s extra parameters hold both ``H_left`` and ``H_right``."""
    return _given(rig.extra.get("H_left")) and _given(rig.extra.get("H_right"))


def _given(value) -> bool:
    if value is None:
        return False
    try:
        return np.asarray(value).size > 0
    except (TypeError, ValueError):
        return True  # present but malformed: let validation name the problem


def validate_homography(H, name: str, image_size) -> np.ndarray:
    """``H`` (9 numbers or 3x3) as a float64 (3, 3) homography scaled to ``H[2, 2] = 1``,
    checked against the raw image it rectifies.

    Checks, each failing with one :class:`RigError` line naming ``name``: 9 finite
    numbers; invertible (condition number below 1e12); the image's line at infinity
    does not cross the ``(width, height)`` image (the homographic scale keeps one sign over
    its four corners, so the rectified image is not torn apart); the image covers at
    least :data:`MIN_RECTIFIED_COVERAGE` of the rectified image of the same size (else the
    homography belongs to another image size or another rig).
    """
    try:
        a = np.asarray(H, dtype=np.float64)
    except (TypeError, ValueError):
        raise RigError(f"{name} must be 9 numbers (a row-major 3x3 homography), got {H!r}") from None
    if a.size != 9:
        raise RigError(f"{name} must be 9 numbers (a row-major 3x3 homography), got {a.size}")
    a = a.reshape(3, 3)
    if not np.all(np.isfinite(a)):
        raise RigError(f"{name} has non-finite entries")
    s = np.linalg.svd(a, compute_uv=False)
    if s[0] == 0 or s[-1] < 1e-12 * s[0]:
        raise RigError(f"{name} is singular (not invertible)")
    w, h = (int(v) for v in image_size)
    corners = np.array([[-0.5, -0.5, 1.0], [w - 0.5, -0.5, 1.0], [w - 0.5, h - 0.5, 1.0],
                        [-0.5, h - 0.5, 1.0]])
    scale = corners @ a[2]
    if not (np.all(scale > 0) or np.all(scale < 0)):
        raise RigError(f"{name} sends part of the {w}x{h} image to infinity (its line at infinity "
                       "crosses the image): not a rectifying homography of this image size")
    a = a / a[2, 2]  # non-zero: pixel (0, 0) lies inside the corners, where the scale keeps its sign
    quad = apply_homography(a, corners[:, :2]).astype(np.float32)
    frame = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]], np.float32)
    if cv2.contourArea(quad, oriented=True) < 0:
        quad = quad[::-1].copy()
    overlap, _ = cv2.intersectConvexConvex(quad, frame)
    coverage = float(overlap) / float(w * h)
    if coverage < MIN_RECTIFIED_COVERAGE:
        raise RigError(f"{name} maps the {w}x{h} image onto only {100 * coverage:.0f}% of the rectified "
                       f"image (at least {100 * MIN_RECTIFIED_COVERAGE:.0f}% expected): the homography "
                       "belongs to another image size or rig")
    return a


def rectification_for_rig(rig, *, method: str | None = None, H_left=None, H_right=None,
                          matches=None) -> Rectification:
    """The :class:`Rectification` of ``rig``.

    Args:
        rig: a :class:`~canopy_stereo.io.rig.Rig` (world-frame ``P``, image size, extras).
        method: ``"fusiello"`` or ``"hartley"``; None or ``""`` = the rig's ``method``
            extra parameter, else ``"fusiello"``.
        H_left, H_right: Hartley homographies (9 numbers or 3x3, original ideal pixel ->
            rectified pixel) overriding the rig's ``H_left``/``H_right``; ignored by Fusiello.
        matches: ``(x_left, x_right)``, (N, 2) matched ideal (undistorted) pixels:
            estimate the Hartley homographies from them (:func:`hartley_rectify`) instead
            of reading them; only with method ``hartley``.

    Fusiello is computed from the rig's ``P`` matrices (stored homographies are not read:
    they are derived data). Hartley takes the homographies given, else the rig's, else
    estimates them from ``matches``; the disparity range it suggests is the rig's
    ``disp_min``/``disp_max`` when both are set (``canopy-stereo rectify`` writes them),
    else the estimate's. Homographies read or estimated are checked by
    :func:`validate_homography`. Raises :class:`RigError` naming the problem.
    """
    chosen = rig_rectification_method(rig, method)
    if chosen == "fusiello":
        if matches is not None:
            raise RigError("matches give a Hartley rectification; the method here is fusiello")
        return fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    size = rig.image_size
    if matches is not None:
        x_left, x_right = matches
        rect = hartley_rectify(x_left, x_right, size)
        for name, H in (("H_left", rect.H_left), ("H_right", rect.H_right)):
            try:
                validate_homography(H, name, size)
            except RigError as exc:
                raise RigError(f"Hartley rectification from {rect.n_inliers} matches failed: {exc}") from None
        return rect
    H_left = H_left if _given(H_left) else rig.extra.get("H_left")
    H_right = H_right if _given(H_right) else rig.extra.get("H_right")
    if not (_given(H_left) and _given(H_right)):
        raise RigError("method hartley needs H_left and H_right (computed offline with "
                       "canopy-stereo rectify --method hartley)")
    Hs = [validate_homography(H, name, size) for name, H in (("H_left", H_left), ("H_right", H_right))]
    drange = None
    if "disp_min" in rig.extra and "disp_max" in rig.extra:
        try:
            drange = (int(rig.extra["disp_min"]), int(rig.extra["disp_max"]))
        except (TypeError, ValueError):
            raise RigError(f"disp_min/disp_max must be whole numbers of pixels, got "
                           f"{rig.extra['disp_min']!r}/{rig.extra['disp_max']!r}") from None
    return Rectification(H_left=Hs[0], H_right=Hs[1], size=size, method="hartley",
                         disparity_range=drange)
