"""Rigid transforms of 3-D points as 4x4 homogeneous matrices.

A transform ``T`` (4, 4) maps points of a source frame to a target frame:
``x_target = R @ x_source + t`` with ``R = T[:3, :3]`` (rotation, ``det = +1``)
and ``t = T[:3, 3]`` (world units). A view's *pose* is the transform from its
rig frame (the world frame of its rig file) to the common world frame.

Small motions are written as 6-vectors ``xi = (omega, tau)``: ``omega`` a
rotation vector (axis times angle, radians) and ``tau`` a translation, applied
on the left: ``T <- exp(xi) T`` with ``exp(xi) = [Rot(omega) | tau]``.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError


def make_transform(R=None, t=None) -> np.ndarray:
    """(4, 4) transform from a rotation ``R`` (3, 3) and translation ``t`` (3,)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, np.float64).reshape(3, 3)
    if t is not None:
        T[:3, 3] = np.asarray(t, np.float64).reshape(3)
    return T


def check_transform(T, name: str = "transform", *, tol: float = 1e-4) -> np.ndarray:
    """Return ``T`` as a float64 (4, 4) rigid transform or raise :class:`CanopyStereoError`.

    Accepts 16 numbers (row-major) or a 4x4 nested list. Rejects non-finite
    entries, a last row other than ``0 0 0 1``, and a rotation block that is
    not orthonormal with determinant +1 within ``tol`` (a scaled or mirrored
    matrix is not a pose).
    """
    try:
        arr = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        raise CanopyStereoError(f"{name} is not a numeric 4x4 matrix") from None
    if arr.size == 16:
        arr = arr.reshape(4, 4)
    if arr.shape != (4, 4):
        raise CanopyStereoError(f"{name} must be a 4x4 matrix (16 numbers, row-major), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CanopyStereoError(f"{name} has non-finite entries")
    if not np.allclose(arr[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise CanopyStereoError(f"{name}: last row must be 0 0 0 1, got {arr[3].tolist()}")
    R = arr[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > tol or np.linalg.det(R) < 0:
        raise CanopyStereoError(f"{name}: the 3x3 block is not a rotation (R R^T deviates from I by "
                                f"{err:.2g}, det {np.linalg.det(R):.3f}); a pose is rotation + translation")
    return arr


def invert_transform(T) -> np.ndarray:
    """Inverse of a rigid transform: ``[R^T | -R^T t]``."""
    T = np.asarray(T, np.float64)
    R, t = T[:3, :3], T[:3, 3]
    return make_transform(R.T, -R.T @ t)


def transform_points(T, points) -> np.ndarray:
    """Apply ``T`` (4, 4) to points (N, 3) (or any (..., 3)); NaN rows stay NaN. Returns float64."""
    T = np.asarray(T, np.float64)
    pts = np.asarray(points, np.float64)
    return pts @ T[:3, :3].T + T[:3, 3]


def skew(v) -> np.ndarray:
    """(3, 3) cross-product matrix ``[v]_x`` with ``[v]_x w = v x w``."""
    x, y, z = np.asarray(v, np.float64).reshape(3)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_from_rotvec(omega) -> np.ndarray:
    """Rotation matrix (3, 3) of a rotation vector (axis * angle in radians), Rodrigues."""
    omega = np.asarray(omega, np.float64).reshape(3)
    theta = float(np.linalg.norm(omega))
    K = skew(omega)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + np.sin(theta) / theta * K + (1.0 - np.cos(theta)) / theta ** 2 * K @ K


def rotvec_from_rotation(R) -> np.ndarray:
    """Rotation vector (3,) (axis * angle, radians, angle in [0, pi]) of a rotation matrix."""
    R = np.asarray(R, np.float64)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(cos))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if theta < 1e-6:
        return 0.5 * w
    if np.pi - theta < 1e-4:  # near 180 degrees: axis from the symmetric part
        B = (R + np.eye(3)) / 2.0
        axis = B[int(np.argmax(np.diag(B)))]
        axis = axis / np.linalg.norm(axis)
        if axis @ w < 0:
            axis = -axis
        return axis * theta
    return w * (theta / (2.0 * np.sin(theta)))


def rotation_about_axis(axis, angle_rad: float) -> np.ndarray:
    """Rotation (3, 3) by ``angle_rad`` about the direction ``axis`` (right-handed)."""
    a = np.asarray(axis, np.float64).reshape(3)
    n = np.linalg.norm(a)
    if n == 0:
        raise CanopyStereoError("rotation axis must be non-zero")
    return rotation_from_rotvec(a / n * float(angle_rad))


def rotation_about_line(point, axis, angle_rad: float) -> np.ndarray:
    """(4, 4) rotation by ``angle_rad`` about the line through ``point`` along ``axis``."""
    R = rotation_about_axis(axis, angle_rad)
    p = np.asarray(point, np.float64).reshape(3)
    return make_transform(R, p - R @ p)


def exp_se3(xi) -> np.ndarray:
    """(4, 4) transform of a small motion ``xi = (omega, tau)``: ``[Rot(omega) | tau]``."""
    xi = np.asarray(xi, np.float64).reshape(6)
    return make_transform(rotation_from_rotvec(xi[:3]), xi[3:])


def log_se3(T) -> np.ndarray:
    """Inverse of :func:`exp_se3`: ``(rotvec(R), t)`` (6,)."""
    T = np.asarray(T, np.float64)
    return np.concatenate([rotvec_from_rotation(T[:3, :3]), T[:3, 3]])


def rotation_angle_deg(R) -> float:
    """Angle of a rotation matrix in degrees, in [0, 180]."""
    R = np.asarray(R, np.float64)
    return float(np.degrees(np.arccos(np.clip((np.trace(R[:3, :3]) - 1.0) / 2.0, -1.0, 1.0))))


def transform_error(T_est, T_true, *, centre=None) -> tuple[float, float]:
    """(translation error, rotation error in degrees) of an estimated transform.

    The translation error is measured at ``centre`` (3,) in the source frame
    (e.g. the middle of the scene): ``|T_est c - T_true c|``, in world units.
    It defaults to the origin, i.e. ``|t_est - t_true|``. The rotation error
    is the angle of ``R_est R_true^T``.
    """
    T_est, T_true = np.asarray(T_est, np.float64), np.asarray(T_true, np.float64)
    c = np.zeros(3) if centre is None else np.asarray(centre, np.float64).reshape(3)
    dt = float(np.linalg.norm(transform_points(T_est, c) - transform_points(T_true, c)))
    return dt, rotation_angle_deg(T_est[:3, :3] @ T_true[:3, :3].T)


def rigid_fit(source, target, *, weights=None) -> np.ndarray:
    """Least-squares rigid transform ``T`` with ``target ~ T source`` (Kabsch / Umeyama, no scale).

    Args:
        source, target: (N, 3) corresponding points, N >= 3, not collinear.
        weights: optional (N,) non-negative weights.

    Returns:
        (4, 4) transform minimising ``sum w |R s + t - d|^2``.
    """
    src = np.asarray(source, np.float64).reshape(-1, 3)
    dst = np.asarray(target, np.float64).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise CanopyStereoError(f"rigid fit needs >= 3 point pairs, got {len(src)} and {len(dst)}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, np.float64).reshape(-1)
    w = w / w.sum()
    cs, cd = w @ src, w @ dst
    H = (src - cs).T @ ((dst - cd) * w[:, None])
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
    R = Vt.T @ D @ U.T
    return make_transform(R, cd - R @ cs)


def rigid_fit_batch(source, target) -> np.ndarray:
    """Rigid fits of many small point sets at once.

    Args:
        source, target: (M, K, 3) M sets of K corresponding points.

    Returns:
        (M, 4, 4) transforms, one per set (degenerate sets give some rotation;
        callers score them by their inliers).
    """
    src = np.asarray(source, np.float64)
    dst = np.asarray(target, np.float64)
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    H = np.einsum("mki,mkj->mij", src - cs[:, None], dst - cd[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.transpose(Vt, (0, 2, 1))
    d = np.sign(np.linalg.det(V @ np.transpose(U, (0, 2, 1))))
    d[d == 0] = 1.0
    V[:, :, 2] *= d[:, None]
    R = V @ np.transpose(U, (0, 2, 1))
    T = np.tile(np.eye(4), (len(src), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = cd - np.einsum("mij,mj->mi", R, cs)
    return T
