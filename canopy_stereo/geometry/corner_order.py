"""Which detected chessboard corner is which, resolved from the geometry of all placements.

Corner order. ``cv2.findChessboardCorners`` may return the corners of any board
starting from any of its ends, and a board whose corner counts are both odd or
both even (7x5) looks the same turned by 180 degrees, so which detected corner
is the first inner corner cannot be read from one image. It is resolved from
the geometry (:func:`resolve_corner_order`): each camera must be ONE projective
camera for all placements. For three placements far apart (different lines of
the sheet) every combination of the grid's symmetries (as detected, turned 180
degrees, mirrored rows or columns, and for square patterns the transposes) is
fitted by the normalised DLT; only the true order lets one camera explain all
three. The order of every other placement is the symmetry that this provisional
camera reprojects best, and the choice is repeated with the camera refitted on
all placements until it no longer changes. A placement whose corners still do
not fit (reprojection RMS above a tolerance) contradicts its images and is
reported by pair (:class:`~canopy_stereo.errors.CalibrationError`).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.calibration import dlt_projection, gold_standard_projection
from canopy_stereo.geometry.camera import project


# ----------------------------------------------------------------------------- detection
def board_symmetries(pattern) -> list[tuple[str, np.ndarray]]:
    """Re-orderings of a ``(cols, rows)`` grid onto itself: ``[(name, index (cols*rows,))]``.

    ``corners[index]`` re-orders detected corners. Always: as detected, turned
    180 degrees, rows mirrored, columns mirrored; for square patterns also the
    four transposed orders. The first entry is the identity.
    """
    cols, rows = pattern
    grid = np.arange(cols * rows).reshape(rows, cols)
    syms = [("as detected", grid), ("turned 180 degrees", grid[::-1, ::-1]),
            ("mirrored left-right", grid[:, ::-1]), ("mirrored top-bottom", grid[::-1, :])]
    if cols == rows:
        syms += [("transposed", grid.T), ("turned 90 degrees", grid.T[:, ::-1]),
                 ("turned 270 degrees", grid.T[::-1, :]), ("anti-transposed", grid.T[::-1, ::-1])]
    return [(name, g.ravel().copy()) for name, g in syms]


# ----------------------------------------------------------------------------- corner order
def _rms(P, X, x) -> float:
    with np.errstate(all="ignore"):
        d = project(P, X) - x
    v = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
    return v if math.isfinite(v) else math.inf


def _handedness(P, X) -> float:
    """+1 when ``P`` images the points ``X`` (N, 3) like a real camera does a
    right-handed world frame (``det(P[:, :3]) > 0`` with the points in front), -1 mirrored."""
    w = np.column_stack([X, np.ones(len(X))]) @ P[2]
    return float(np.sign(np.linalg.det(P[:, :3])) * np.sign(np.mean(w)))


def _spread_seeds(centres: np.ndarray, normals: np.ndarray, count: int = 3) -> list[int]:
    """Indices of ``count`` placements far apart: the first farthest from the mean,
    then each next maximising its distance from the line/plane of those chosen,
    with a bonus for a different board normal."""
    n = len(centres)
    scale = float(np.linalg.norm(centres - centres.mean(0), axis=1).max()) or 1.0
    first = int(np.argmax(np.linalg.norm(centres - centres.mean(0), axis=1)))
    chosen = [first]
    while len(chosen) < min(count, n):
        best, best_score = None, -1.0
        for k in range(n):
            if k in chosen:
                continue
            d = centres[k] - centres[chosen[0]]
            if len(chosen) >= 2:
                u = centres[chosen[1]] - centres[chosen[0]]
                u = u / (np.linalg.norm(u) or 1.0)
                d = d - (d @ u) * u
            turn = min(float(np.linalg.norm(np.cross(normals[k], normals[c]))) for c in chosen)
            score = float(np.linalg.norm(d)) / scale + 0.5 * turn
            if score > best_score:
                best, best_score = k, score
        assert best is not None  # a placement not chosen yet scores >= 0 > -1
        chosen.append(best)
    return chosen


@dataclass
class CornerOrder:
    """Result of :func:`resolve_corner_order` for one camera.

    Attributes:
        index: per view, the (cols*rows,) re-ordering to apply to its detected corners.
        names: per view, the symmetry chosen (``"as detected"``, ``"turned 180 degrees"``, ...).
        rms: per view, the reprojection RMS (pixels) of its re-ordered corners under
            the camera fitted on all views.
        P: (3, 4) the Gold Standard camera fitted on all views.
    """

    index: list
    names: list
    rms: np.ndarray
    P: np.ndarray


def resolve_corner_order(world_points, detections, pattern, *, max_rms_px: float = 3.0,
                         max_iterations: int = 5, view_names=None) -> CornerOrder:
    """Put every view's detected corners into the order of its world points.

    Args:
        world_points: per view, (cols*rows, 3) world corners (:func:`board_world_points`).
        detections: per view, (cols*rows, 2) detected corners in OpenCV's order.
        pattern: ``(cols, rows)``.
        max_rms_px: a view whose best order still reprojects worse than this (pixels)
            under the camera of all the others contradicts its placement.
        view_names: per view, a name for error messages (default ``pair <k>``).

    Returns:
        :class:`CornerOrder`.

    Raises:
        CalibrationError: fewer than 3 views; no 3 views admit one camera
            (placements and images disagree); the order is ambiguous (all boards
            symmetric about one axis); or a view contradicts its placement
            (the message names it and its reprojection RMS).
    """
    n = len(world_points)
    names = list(view_names) if view_names is not None else [f"pair {k}" for k in range(n)]
    if n < 3:
        raise CalibrationError(f"need the board in at least 3 pairs to calibrate, found it in {n}")
    syms = board_symmetries(pattern)
    W = [np.asarray(w, np.float64) for w in world_points]
    D = [np.asarray(d, np.float64) for d in detections]
    cols, rows = pattern
    centres = np.array([w.mean(0) for w in W])
    normal_list = []
    for w in W:
        g = w.reshape(rows, cols, 3)
        nv = np.cross(g[0, -1] - g[0, 0], g[-1, 0] - g[0, 0])
        normal_list.append(nv / (np.linalg.norm(nv) or 1.0))
    normals = np.array(normal_list)

    # 1. seeds: three views far apart; try every combination of symmetries
    order = _spread_seeds(centres, normals, 3)
    seed_sets = [order]
    rest = [k for k in np.argsort(-np.linalg.norm(centres - centres.mean(0), axis=1)) if k not in order]
    for k in rest[:6]:  # fall-back seeds if a seed itself contradicts its images
        seed_sets.append([order[0], order[1], int(k)])
        seed_sets.append([order[0], int(k), order[2]])
    P = None
    best_info = None
    for seeds in seed_sets:
        X = np.vstack([W[s] for s in seeds])
        scores = []
        for combo in itertools.product(range(len(syms)), repeat=len(seeds)):
            x = np.vstack([D[s][syms[c][1]] for s, c in zip(seeds, combo)])
            try:
                Pc = dlt_projection(X, x)
            except (CalibrationError, np.linalg.LinAlgError):
                continue
            scores.append((_rms(Pc, X, x), _handedness(Pc, X), combo, Pc))
        if not scores:
            continue
        scores.sort(key=lambda t: t[0])
        best = scores[0][0]
        best_info = (seeds, best)
        if best > max_rms_px * 3:
            continue  # a seed contradicts its images: try other seeds
        # combinations that explain the seeds as well as the best one
        tied = [t for t in scores if t[0] <= 3.0 * best + 1.0]
        proper = [t for t in tied if t[1] > 0]
        if len(tied) == 1:
            P = tied[0][3]
        elif len(proper) == 1:
            # a mirror image of the layout fits as well (all boards symmetric about
            # one plane): a real camera does not mirror a right-handed world frame
            P = proper[0][3]
        else:
            seeds_txt = ", ".join(names[s] for s in seeds)
            raise CalibrationError(
                f"the corner order is ambiguous ({seeds_txt}): {len(tied)} orders of their corners fit "
                f"equally well ({best:.2f} px); the boards are placed symmetrically; add placements "
                "that break the symmetry (other lines, heights or turns)")
        break
    if P is None:
        seeds, rms0 = best_info if best_info else (order, math.inf)
        raise CalibrationError(
            "the placements do not match the images: no single camera sees the boards of "
            f"{', '.join(names[s] for s in seeds)} where they are placed (best {rms0:.1f} px); check "
            "the pair order, the pattern, the square size and the axes")

    # 2. every view: the symmetry the camera explains best; refit; repeat until stable
    choice = [0] * n
    for _ in range(max(1, int(max_iterations))):
        new = []
        for k in range(n):
            r = [_rms(P, W[k], D[k][idx]) for _, idx in syms]
            new.append(int(np.argmin(r)))
        good = [k for k in range(n) if _rms(P, W[k], D[k][syms[new[k]][1]]) <= max_rms_px * 3]
        if len(good) < 3:
            good = list(range(n))
        X = np.vstack([W[k] for k in good])
        x = np.vstack([D[k][syms[new[k]][1]] for k in good])
        P, _ = gold_standard_projection(X, x)
        if new == choice:
            break
        choice = new
    choice = []
    for k in range(n):
        r = [_rms(P, W[k], D[k][idx]) for _, idx in syms]
        choice.append(int(np.argmin(r)))
    X = np.vstack([W[k] for k in range(n)])
    x = np.vstack([D[k][syms[choice[k]][1]] for k in range(n)])
    rms = np.array([_rms(P, W[k], D[k][syms[choice[k]][1]]) for k in range(n)])
    bad = np.flatnonzero(rms > max_rms_px)
    if bad.size:
        # judge each suspect against the camera of all the other views
        worst: tuple[int, float] | None = None
        for k in bad:
            others = [j for j in range(n) if j != k and rms[j] <= max_rms_px] or [j for j in range(n) if j != k]
            Xo = np.vstack([W[j] for j in others])
            xo = np.vstack([D[j][syms[choice[j]][1]] for j in others])
            try:
                Po = dlt_projection(Xo, xo)
            except CalibrationError:
                continue
            rk = min(_rms(Po, W[k], D[k][idx]) for _, idx in syms)
            if rk > max_rms_px and (worst is None or rk > worst[1]):
                worst = (int(k), rk)
        if worst is not None:
            k, r_px = worst
            raise CalibrationError(
                f"{names[k]} contradicts its placement: its corners are {r_px:.1f} px (RMS) from where "
                f"the camera fitted on the other pairs puts them (tolerance {max_rms_px:g} px); check its "
                "origin, axes and the pair order")
    P, _ = gold_standard_projection(X, x)
    rms = np.array([_rms(P, W[k], D[k][syms[choice[k]][1]]) for k in range(n)])
    return CornerOrder(index=[syms[c][1] for c in choice], names=[syms[c][0] for c in choice],
                       rms=rms, P=P)
