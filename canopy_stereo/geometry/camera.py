"""Pinhole camera model from a 3x4 projection matrix.

A camera ``P = K [R | -R C]`` maps homogeneous world points ``X`` (world units,
e.g. mm) to homogeneous pixels ``x ~ P X``. ``K`` is the 3x3 upper-triangular
intrinsic matrix (pixels), ``R`` the world-to-camera rotation and ``C`` the
camera centre in world coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from canopy_stereo.errors import RigError


def validate_projection(P, name: str = "P") -> np.ndarray:
    """Return ``P`` as a float64 (3, 4) array or raise :class:`RigError`.

    Rejects wrong shapes, non-finite entries and matrices whose left 3x3 block
    is singular (rank < 3), which have no finite camera centre.
    """
    try:
        arr = np.asarray(P, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise RigError(f"{name} is not numeric: {exc}") from None
    if arr.size == 12 and arr.ndim == 1:
        arr = arr.reshape(3, 4)
    if arr.shape != (3, 4):
        raise RigError(f"{name} must be a 3x4 matrix (12 numbers), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise RigError(f"{name} has non-finite entries (NaN or inf)")
    M = arr[:, :3]
    s = np.linalg.svd(M, compute_uv=False)
    if s[0] == 0 or s[-1] / s[0] < 1e-12:
        raise RigError(f"{name} is rank-deficient: its left 3x3 block has rank < 3")
    return arr


@dataclass(frozen=True)
class Camera:
    """Decomposed camera: ``P ~ K @ [R | -R @ C]``.

    Attributes:
        K: (3, 3) intrinsics in pixels, positive diagonal, ``K[2, 2] == 1``.
        R: (3, 3) world-to-camera rotation, ``det(R) == +1``.
        C: (3,) camera centre in world units.
    """

    K: np.ndarray
    R: np.ndarray
    C: np.ndarray

    @property
    def t(self) -> np.ndarray:
        """(3,) translation ``t = -R C`` (world units)."""
        return -self.R @ self.C

    @property
    def P(self) -> np.ndarray:
        """(3, 4) projection matrix ``K [R | t]``."""
        return compose_projection(self.K, self.R, self.C)

    @property
    def optical_axis(self) -> np.ndarray:
        """(3,) unit viewing direction in world coordinates."""
        return self.R[2].copy()


def compose_projection(K, R, C) -> np.ndarray:
    """Build ``P = K [R | -R C]`` (3x4) from intrinsics, rotation and centre."""
    K = np.asarray(K, np.float64)
    R = np.asarray(R, np.float64)
    C = np.asarray(C, np.float64).reshape(3)
    return K @ np.hstack([R, (-R @ C)[:, None]])


def camera_centre(P) -> np.ndarray:
    """Camera centre ``C`` (3,) in world units: the right null vector of ``P``."""
    P = validate_projection(P)
    return -np.linalg.solve(P[:, :3], P[:, 3])


def decompose_projection(P) -> Camera:
    """Decompose ``P`` into ``K``, ``R``, ``C`` (Hartley & Zisserman, sec. 6.2.4).

    ``P`` is only defined up to scale (including sign); the sign is chosen so
    that points in front of the camera have positive depth, ``det(R) = +1``
    and ``K`` has a positive diagonal with ``K[2, 2] = 1``.
    """
    P = validate_projection(P)
    M = P[:, :3]
    if np.linalg.det(M) < 0:
        M = -M
    K, R = scipy.linalg.rq(M)
    signs = np.diag(np.sign(np.diag(K)))
    K = K @ signs
    R = signs @ R
    if np.linalg.det(R) < 0:  # cannot happen once det(M) > 0 and diag(K) > 0
        R = -R
    K = K / K[2, 2]
    return Camera(K=K, R=R, C=camera_centre(P))


def project(P, X) -> np.ndarray:
    """Project world points ``X`` (N, 3) through ``P``; returns pixels (N, 2)."""
    P = np.asarray(P, np.float64)
    X = np.asarray(X, np.float64).reshape(-1, 3)
    x = X @ P[:, :3].T + P[:, 3]
    return x[:, :2] / x[:, 2:3]


def point_depth(P, X) -> np.ndarray:
    """Signed depth (N,) of world points in front of camera ``P``, in world units.

    Positive in front of the camera; computed as in H&Z eq. 6.15 so it is
    independent of the scale and sign of ``P``.
    """
    P = np.asarray(P, np.float64)
    X = np.asarray(X, np.float64).reshape(-1, 3)
    M = P[:, :3]
    w = X @ P[2, :3] + P[2, 3]
    return np.sign(np.linalg.det(M)) * w / np.linalg.norm(M[2])


def pixel_rays(P, uv) -> np.ndarray:
    """Unit ray directions (N, 3) in world coordinates through pixels ``uv`` (N, 2).

    Rays start at the camera centre and point into the scene (positive depth).
    """
    P = validate_projection(P)
    uv = np.asarray(uv, np.float64).reshape(-1, 2)
    M = P[:, :3]
    xh = np.hstack([uv, np.ones((len(uv), 1))])
    d = np.linalg.solve(M, xh.T).T
    d *= np.sign(np.linalg.det(M))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def normalize_projection(P) -> np.ndarray:
    """Scale ``P`` so that ``||P[2, :3]|| = 1`` and ``det(P[:, :3]) > 0``.

    With this scaling ``(P X)[2]`` is the depth of ``X`` in world units.
    """
    P = validate_projection(P)
    s = np.linalg.norm(P[2, :3]) * np.sign(np.linalg.det(P[:, :3]))
    return P / s
