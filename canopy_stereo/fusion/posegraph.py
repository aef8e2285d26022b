"""Pose-graph optimisation: spread the drift of a chain of registrations round a loop.

Nodes are view poses ``T_i`` (rig frame of view ``i`` -> world). An edge
``(i, j, T_ij, Omega_ij)`` is a measured relative pose mapping view ``j``'s
frame into view ``i``'s (``T_i^-1 T_j ~ T_ij``, the result of registering
``j`` onto ``i``) with its 6x6 information matrix ``Omega`` (from ICP, for a
left perturbation in frame ``i``). The edge error is the small motion

    e_ij = log(T_i^-1 T_j T_ij^-1)    (rotation vector, translation)

and the optimiser minimises ``sum e^T Omega e`` (Levenberg-Marquardt in
``scipy.optimize.least_squares``) over left perturbations of every pose but the
fixed one. When views go all the way round, the chain ``0-1-...-(n-1)`` plus
the closing edge ``(n-1) -> 0`` over-determines the poses and the accumulated
error of the chain is distributed over all edges according to their weights.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.transforms import exp_se3, invert_transform, log_se3, rotation_angle_deg


@dataclass
class PoseGraphEdge:
    """Relative pose measurement: ``T_i^-1 T_j ~ transform`` with ``information`` (6, 6)."""

    i: int
    j: int
    transform: np.ndarray
    information: np.ndarray


def edge_error(T_i, T_j, T_ij) -> np.ndarray:
    """(6,) error ``log(T_i^-1 T_j T_ij^-1)`` (rotation vector, translation)."""
    return log_se3(invert_transform(T_i) @ T_j @ invert_transform(T_ij))


def edge_residuals(poses, edges) -> list[tuple[float, float]]:
    """Per edge ``(translation error in world units, rotation error in degrees)``."""
    out = []
    for e in edges:
        E = invert_transform(poses[e.i]) @ poses[e.j] @ invert_transform(e.transform)
        out.append((float(np.linalg.norm(E[:3, 3])), rotation_angle_deg(E[:3, :3])))
    return out


def _sqrt_information(info) -> np.ndarray:
    info = np.asarray(info, np.float64)
    info = 0.5 * (info + info.T)
    reg = 1e-9 * max(np.trace(info), 1e-12)
    try:
        return np.linalg.cholesky(info + reg * np.eye(6)).T
    except np.linalg.LinAlgError:
        w, V = np.linalg.eigh(info)
        return (V * np.sqrt(np.clip(w, reg, None))).T


def optimize_pose_graph(poses, edges, *, fixed: int = 0, max_evaluations: int = 200) -> list[np.ndarray]:
    """Poses (list of (4, 4)) that best agree with the edges; ``poses[fixed]`` is kept.

    Args:
        poses: initial poses, e.g. chained from the sequential registrations.
        edges: :class:`PoseGraphEdge` list (every node must be reached).
        fixed: index of the pose held constant (gauge).
    """
    n = len(poses)
    init = [np.asarray(T, np.float64) for T in poses]
    if n < 2 or not edges:
        return init
    for e in edges:
        if not (0 <= e.i < n and 0 <= e.j < n) or e.i == e.j:
            raise CanopyStereoError(f"pose graph edge ({e.i}, {e.j}) is invalid for {n} poses")
    free = [k for k in range(n) if k != fixed]
    slot = {k: s for s, k in enumerate(free)}
    sqrt_info = [_sqrt_information(e.information) for e in edges]
    inv_meas = [invert_transform(e.transform) for e in edges]

    def current(x):
        out = list(init)
        for k in free:
            s = slot[k]
            out[k] = exp_se3(x[6 * s:6 * s + 6]) @ init[k]
        return out

    def residuals(x):
        P = current(x)
        r = np.empty(6 * len(edges))
        for m, e in enumerate(edges):
            err = log_se3(invert_transform(P[e.i]) @ P[e.j] @ inv_meas[m])
            r[6 * m:6 * m + 6] = sqrt_info[m] @ err
        return r

    x0 = np.zeros(6 * len(free))
    sol = least_squares(residuals, x0, method="lm", max_nfev=max_evaluations * (len(x0) + 1),
                        x_scale="jac")
    return current(sol.x)
