"""Camera calibration in a world frame from 2D-3D correspondences (paper sec. 2.1).

Gold Standard algorithm (Hartley & Zisserman, alg. 7.1): normalised DLT for an
initial ``P``, then Levenberg-Marquardt on the geometric reprojection error.
The stereo result is checked as in the paper's Table 1: every known 3D point is
triangulated from its two projections and compared with its true position.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.camera import normalize_projection, project
from canopy_stereo.geometry.triangulation import triangulate_dlt

#: Smallest-to-largest singular value ratio of the centred 3D points below which
#: they are considered coplanar (DLT is then degenerate).
COPLANARITY_RATIO = 1e-4


def _normalising_transform(points: np.ndarray) -> np.ndarray:
    """Similarity moving ``points`` (N, k) to centroid 0 and mean distance sqrt(k)."""
    k = points.shape[1]
    c = points.mean(axis=0)
    dist = np.linalg.norm(points - c, axis=1).mean()
    s = np.sqrt(k) / dist if dist > 0 else 1.0
    T = np.eye(k + 1)
    T[:k, :k] *= s
    T[:k, k] = -s * c
    return T


def _check_correspondences(X, x) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, np.float64)
    x = np.asarray(x, np.float64)
    if X.ndim != 2 or X.shape[1] != 3:
        raise CalibrationError(f"3D points must be (N, 3), got shape {X.shape}")
    if x.ndim != 2 or x.shape[1] != 2:
        raise CalibrationError(f"image points must be (N, 2), got shape {x.shape}")
    if len(X) != len(x):
        raise CalibrationError(f"{len(X)} 3D points but {len(x)} image points")
    if len(X) < 6:
        raise CalibrationError(f"need at least 6 2D-3D correspondences, got {len(X)}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(x))):
        raise CalibrationError("correspondences contain non-finite values")
    s = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if s[0] == 0 or s[2] / s[0] < COPLANARITY_RATIO:
        raise CalibrationError(
            "the 3D points are coplanar (or collinear): DLT needs points spread in depth; "
            "use a 3D target or chessboard calibration")
    return X, x


def dlt_projection(X, x) -> np.ndarray:
    """Normalised DLT estimate of ``P`` (3, 4) from >= 6 world points ``X`` and pixels ``x``.

    Both point sets are normalised (Hartley), the 2N x 12 system is solved by
    SVD and the result denormalised. ``P`` is scaled with :func:`normalize_projection`.
    """
    X, x = _check_correspondences(X, x)
    T = _normalising_transform(x)
    U = _normalising_transform(X)
    xn = (T @ np.column_stack([x, np.ones(len(x))]).T).T
    Xn = (U @ np.column_stack([X, np.ones(len(X))]).T).T
    n = len(X)
    A = np.zeros((2 * n, 12))
    A[0::2, 4:8] = -xn[:, 2:3] * Xn
    A[0::2, 8:12] = xn[:, 1:2] * Xn
    A[1::2, 0:4] = xn[:, 2:3] * Xn
    A[1::2, 8:12] = -xn[:, 0:1] * Xn
    _, _, Vt = np.linalg.svd(A, full_matrices=False)
    Pn = Vt[-1].reshape(3, 4)
    P = np.linalg.solve(T, Pn @ U)
    return normalize_projection(P)


def reprojection_errors(P, X, x) -> np.ndarray:
    """Per-point reprojection error (N,) in pixels."""
    return np.linalg.norm(project(P, X) - np.asarray(x, np.float64), axis=1)


def gold_standard_projection(X, x, *, max_iterations: int = 200, initial=None) -> tuple[np.ndarray, float]:
    """Gold Standard estimate of ``P`` (H&Z alg. 7.1).

    Normalised DLT, then Levenberg-Marquardt (``scipy.optimize.least_squares``,
    ``method="lm"``, analytic Jacobian) over the 12 entries of the normalised
    ``P`` minimising the pixel reprojection error.

    Args:
        X: (N, 3) world points (world units); x: (N, 2) their pixels.
        initial: optional (3, 4) starting ``P`` instead of the DLT estimate (e.g.
            the camera of a nearby data set, to save the DLT).

    Returns:
        ``(P, rms)``: (3, 4) matrix scaled by :func:`normalize_projection` and the
        RMS reprojection error in pixels.
    """
    X, x = _check_correspondences(X, x)
    P0 = dlt_projection(X, x) if initial is None else np.asarray(initial, np.float64).reshape(3, 4)
    T = _normalising_transform(x)
    U = _normalising_transform(X)
    Xn = (U @ np.column_stack([X, np.ones(len(X))]).T).T
    Pn0 = T @ P0 @ np.linalg.inv(U)
    Pn0 /= np.linalg.norm(Pn0)
    Tinv = np.linalg.inv(T)
    n = len(X)

    def residuals(p):
        Pn = p.reshape(3, 4)
        xh = Xn @ (Tinv @ Pn).T
        return (xh[:, :2] / xh[:, 2:3] - x).ravel()

    def jacobian(p):
        # pixel = (Tinv[r] . q) / q_2 with q = Pn Xn (Tinv's last row is (0, 0, 1))
        q = Xn @ p.reshape(3, 4).T                                 # (N, 3)
        J = np.empty((n, 2, 3, 4))
        for r in range(2):
            a = Tinv[r]
            num = q @ a
            dq = a[None, :] / q[:, 2:3]                            # d pixel / d q
            dq[:, 2] -= num / q[:, 2] ** 2
            J[:, r] = dq[:, :, None] * Xn[:, None, :]
        return J.reshape(2 * n, 12)

    res = least_squares(residuals, Pn0.ravel(), jac=jacobian, method="lm",
                        max_nfev=max_iterations * 13, xtol=1e-12, ftol=1e-12)
    P = Tinv @ res.x.reshape(3, 4) @ U
    P = normalize_projection(P)
    rms = float(np.sqrt(np.mean(reprojection_errors(P, X, x) ** 2)))
    return P, rms


@dataclass
class TriangulationCheck:
    """Per-axis errors between known and triangulated 3D points (paper's Table 1).

    Attributes:
        errors: (N, 3) ``X_act - X_est`` in world units.
        distance: (N,) distance of each point from the midpoint of the camera centres.
    """

    errors: np.ndarray
    distance: np.ndarray

    @property
    def mean_abs(self) -> np.ndarray:
        """(3,) mean absolute error per axis."""
        return np.nanmean(np.abs(self.errors), axis=0)

    @property
    def std(self) -> np.ndarray:
        """(3,) standard deviation of the absolute error per axis."""
        return np.nanstd(np.abs(self.errors), axis=0)

    @property
    def max_abs(self) -> np.ndarray:
        """(3,) maximum absolute error per axis."""
        return np.nanmax(np.abs(self.errors), axis=0)

    def table(self, unit: str = "mm") -> str:
        """The error table as text, one row per axis."""
        lines = [f"axis  mean |X_act - X_est| ({unit})  std ({unit})  max ({unit})"]
        for i, axis in enumerate("XYZ"):
            lines.append(f"{axis:>4}  {self.mean_abs[i]:>24.3f}  {self.std[i]:>9.3f}  {self.max_abs[i]:>8.3f}")
        return "\n".join(lines)


def triangulation_check(P_left, P_right, X, x_left, x_right) -> TriangulationCheck:
    """Triangulate known points from their two projections and return the errors."""
    X = np.asarray(X, np.float64)
    Xe = triangulate_dlt(P_left, P_right, x_left, x_right, drop_behind=False)
    from canopy_stereo.geometry.camera import camera_centre

    mid = 0.5 * (camera_centre(P_left) + camera_centre(P_right))
    return TriangulationCheck(errors=X - Xe, distance=np.linalg.norm(X - mid, axis=1))


@dataclass
class StereoCalibration:
    """Result of a world-frame stereo calibration."""

    P_left: np.ndarray
    P_right: np.ndarray
    rms_left: float
    rms_right: float
    check: TriangulationCheck
    D_left: np.ndarray | None = None
    D_right: np.ndarray | None = None
    rms_stereo: float | None = None


def calibrate_stereo_points(X, x_left, x_right) -> StereoCalibration:
    """Gold Standard calibration of both cameras from shared world points.

    Args:
        X: (N, 3) world points (any unit; the rig's world unit).
        x_left, x_right: (N, 2) their pixels in the left and right images.
    """
    P_left, rms_l = gold_standard_projection(X, x_left)
    P_right, rms_r = gold_standard_projection(X, x_right)
    check = triangulation_check(P_left, P_right, X, x_left, x_right)
    return StereoCalibration(P_left, P_right, rms_l, rms_r, check)


#: Margins of the working distance a calibration writes: nearer than the nearest point
#: seen and farther than the farthest, as factors of their distances.
NEAR_MARGIN, FAR_MARGIN = 0.7, 2.0


def observed_working_distance(check: TriangulationCheck, *, metres_per_unit: float) -> tuple[float, float]:
    """``(near_m, far_m)``: the distances (metres) at which the calibration saw its points,
    widened by :data:`NEAR_MARGIN` and :data:`FAR_MARGIN`, rounded to millimetres (the
    rig file's ``near_m``/``far_m``: the disparity range searched covers them)."""
    d = np.asarray(check.distance, np.float64) * float(metres_per_unit)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        raise CalibrationError("no calibration point with a distance: no working distance to write")
    return round(float(d.min()) * NEAR_MARGIN, 3), round(float(d.max()) * FAR_MARGIN, 3)
