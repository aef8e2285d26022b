"""Chessboard stereo calibration (Zhang 2000, via OpenCV) expressed as world-frame P matrices.

The world frame is the left camera of the first pair (x right, y down, z
forward, unit = unit of ``square_size``), or, with ``world_board=i``, the
board of pair ``i`` (origin at its first inner corner, z = 0 on the board).

Images come as sequences of arrays; for files on disk pass
:class:`canopy_stereo.io.images.ImageFiles` (read one pair at a time), e.g.
``calibrate_stereo_chessboard(ImageFiles("left*.png", color=False), ImageFiles("right*.png", color=False))``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.board_corners import detect_board_corners
from canopy_stereo.geometry.calibration import StereoCalibration, TriangulationCheck, triangulation_check
from canopy_stereo.geometry.distortion import undistort_pixels


@dataclass
class ChessboardViews:
    """Detected corners: ``object_points`` (M, 3) board coordinates and, per pair,
    left/right corners (M, 2) in pixels (distorted, as detected)."""

    object_points: np.ndarray
    left: list
    right: list
    names: list
    image_size: tuple[int, int]


def board_points(pattern: tuple[int, int], square_size: float) -> np.ndarray:
    """(cols*rows, 3) inner-corner coordinates on the board plane z = 0, row-major."""
    cols, rows = pattern
    grid = np.zeros((rows * cols, 3), np.float64)
    grid[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * float(square_size)
    return grid


def image_sequence(images, side: str) -> tuple:
    """``(images, names)``: a sequence of images (arrays, or
    :class:`~canopy_stereo.io.images.ImageFiles`) and a name per image for messages
    (the file names, else ``<side>[k]``). Raises :class:`CalibrationError` for an empty
    sequence and for a path or glob (this module reads no files)."""
    if isinstance(images, (str, Path)):
        raise CalibrationError(f"{side} images: {str(images)!r} is a path or glob; read the files with "
                               f"canopy_stereo.io.images.ImageFiles({str(images)!r})")
    if not (hasattr(images, "__len__") and hasattr(images, "__getitem__")):
        images = list(images)
    if len(images) == 0:
        raise CalibrationError(f"no {side} images given")
    names = getattr(images, "names", None) or [f"{side}[{k}]" for k in range(len(images))]
    return images, list(names)


def image_array(image, name: str) -> np.ndarray:
    """``image`` as an array; :class:`CalibrationError` for a path (this module reads no files)."""
    if isinstance(image, (str, Path)):
        raise CalibrationError(f"{name}: {str(image)!r} is a path; read the files with "
                               "canopy_stereo.io.images.ImageFiles")
    return np.asarray(image)


def _grey(image, name: str) -> np.ndarray:
    img = image_array(image, name)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img


def detect_stereo_chessboards(left_images, right_images, *, pattern=(9, 6), square_size=25.0,
                              progress=None) -> ChessboardViews:
    """Detect the board in every pair; pairs where either image misses it are skipped.

    ``left_images``, ``right_images``: sequences of (H, W) grey or (H, W, 3) BGR uint8
    images, paired in order (:class:`~canopy_stereo.io.images.ImageFiles` for files; its
    ``names`` name the pairs). ``progress``: optional ``f(total, left image name)`` called
    before each pair."""
    left_images, left_names = image_sequence(left_images, "left chessboard")
    right_images, right_names = image_sequence(right_images, "right chessboard")
    if len(left_images) != len(right_images):
        raise CalibrationError(f"{len(left_images)} left images but {len(right_images)} right images")
    obj = board_points(pattern, square_size)
    lefts, rights, names, size = [], [], [], None
    for k, (ln, rn) in enumerate(zip(left_names, right_names)):
        if progress is not None:
            progress(len(left_names), ln)
        gl, gr = _grey(left_images[k], ln), _grey(right_images[k], rn)
        if gl.shape != gr.shape:
            raise CalibrationError(f"{ln} and {rn} differ in size")
        if size is None:
            size = (gl.shape[1], gl.shape[0])
        elif size != (gl.shape[1], gl.shape[0]):
            raise CalibrationError(f"{ln} is {gl.shape[1]}x{gl.shape[0]}, expected {size[0]}x{size[1]}")
        cl, cr = detect_board_corners(gl, pattern), detect_board_corners(gr, pattern)
        if cl is None or cr is None:
            continue
        lefts.append(cl)
        rights.append(cr)
        names.append((ln, rn))
    if len(lefts) < 3:
        raise CalibrationError(
            f"the {pattern[0]}x{pattern[1]} board was found in only {len(lefts)} pair(s); need at least 3")
    assert size is not None  # set by the first pair
    return ChessboardViews(obj, lefts, rights, names, size)


def calibrate_stereo_chessboard(left_images, right_images, *, pattern=(9, 6), square_size=25.0,
                                world_board: int | None = None, progress=None) -> StereoCalibration:
    """Zhang calibration of both cameras plus stereo extrinsics, as world-frame ``P`` + ``D``.

    Args:
        left_images, right_images: sequences of images paired in order (see
            :func:`detect_stereo_chessboards`; :class:`~canopy_stereo.io.images.ImageFiles` for files).
        pattern: inner corners ``(cols, rows)``.
        square_size: board square side in world units (e.g. 25 for mm).
        world_board: index of the pair whose board defines the world frame;
            None = the left camera of the first pair.

    Returns:
        A :class:`StereoCalibration` with ``P``/``D`` per camera, the stereo
        RMS (``rms_stereo``, pixels) and the corner triangulation check.
    """
    views = detect_stereo_chessboards(left_images, right_images, pattern=pattern, square_size=square_size,
                                      progress=progress)
    obj = [views.object_points.astype(np.float32).reshape(-1, 1, 3)] * len(views.left)
    il = [c.astype(np.float32).reshape(-1, 1, 2) for c in views.left]
    ir = [c.astype(np.float32).reshape(-1, 1, 2) for c in views.right]
    size = views.image_size
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-6)
    rms_l, K1, D1, rv1, tv1 = cv2.calibrateCamera(obj, il, size, None, None, criteria=crit)
    rms_r, K2, D2, _, _ = cv2.calibrateCamera(obj, ir, size, None, None, criteria=crit)
    out = cv2.stereoCalibrate(obj, il, ir, K1, D1, K2, D2, size, flags=cv2.CALIB_FIX_INTRINSIC,
                              criteria=crit)
    rms, K1, D1, K2, D2, R, T = out[:7]
    T = np.asarray(T, np.float64).reshape(3, 1)
    R = np.asarray(R, np.float64)
    if world_board is None:
        R_w, t_w = np.eye(3), np.zeros((3, 1))
    else:
        if not 0 <= world_board < len(views.left):
            raise CalibrationError(f"world_board {world_board} out of range 0..{len(views.left) - 1}")
        R_w, _ = cv2.Rodrigues(np.asarray(rv1[world_board], np.float64).reshape(3, 1))
        t_w = np.asarray(tv1[world_board], np.float64).reshape(3, 1)
    # world -> left camera: x_l = R_w X + t_w; left -> right: x_r = R x_l + T
    P_left = K1 @ np.hstack([R_w, t_w])
    P_right = K2 @ np.hstack([R @ R_w, R @ t_w + T])
    D1, D2 = np.asarray(D1, np.float64).ravel(), np.asarray(D2, np.float64).ravel()
    # triangulation check of every corner, in the world frame
    X_all, xl_all, xr_all = [], [], []
    for i, (cl, cr) in enumerate(zip(views.left, views.right)):
        Rb, _ = cv2.Rodrigues(np.asarray(rv1[i], np.float64).reshape(3, 1))
        tb = np.asarray(tv1[i], np.float64).reshape(3, 1)
        Xc = (Rb @ views.object_points.T + tb)          # board -> left camera
        Xw = (R_w.T @ (Xc - t_w)).T                      # left camera -> world
        X_all.append(Xw)
        xl_all.append(undistort_pixels(P_left, D1, cl))
        xr_all.append(undistort_pixels(P_right, D2, cr))
    check = triangulation_check(P_left, P_right, np.vstack(X_all), np.vstack(xl_all), np.vstack(xr_all))
    return StereoCalibration(P_left=P_left, P_right=P_right, rms_left=float(rms_l), rms_right=float(rms_r),
                             check=check, D_left=D1, D_right=D2, rms_stereo=float(rms))


def plot_triangulation_errors(check: TriangulationCheck, path, *, unit: str = "mm") -> None:
    """Per-axis error against distance (the paper's Figure 5) as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharex=True)
    for i, (ax, name) in enumerate(zip(axes, "XYZ")):
        ax.scatter(check.distance, check.errors[:, i], s=6, alpha=0.6)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"error in {name} (mean |e| {check.mean_abs[i]:.2f} {unit})")
        ax.set_xlabel(f"distance from rig ({unit})")
        ax.set_ylabel(f"{name}_act - {name}_est ({unit})")
    fig.tight_layout()
    fig.savefig(str(path), dpi=110)
    plt.close(fig)
