"""World-rig calibration from photographs of a chessboard at known places (paper sec. 2.1).

The paper calibrates both cameras in one world frame: an A0 sheet on the floor
carries a 2D x-z coordinate system with three lines through its origin (the
middle line and two lines turned -10 and +10 degrees about the origin, marks
every 50 mm), a vertical chessboard stands at known marks, and the world
coordinates of its inner corners follow from where it stands. The Gold Standard
algorithm (normalised DLT + Levenberg-Marquardt,
:func:`~canopy_stereo.geometry.calibration.gold_standard_projection`) then gives
``P_left`` and ``P_right`` from the detected corners.

The board's place in each image pair is a *placement* (:class:`BoardPlacement`):
the world position of the board's first inner corner and the unit vectors along
its rows (``x_axis``) and down its columns (``y_axis``). Inner corner ``(i, j)``
(column ``i`` of ``cols``, row ``j`` of ``rows``) is at
``origin + square * (i * x_axis + j * y_axis)``, in the row-major order of
:func:`board_world_points` (OpenCV's order for a ``(cols, rows)`` pattern).

Placements file (YAML; read and written by :mod:`canopy_stereo.io.placements`,
parsed by :func:`placements_from_dict`)::

    pattern: 7x5          # inner corners, columns x rows
    square: 50            # world units
    unit: mm
    placements:           # one per image pair, in the sorted order of the globs
      - pair: 0
        origin: [X, Y, Z]     # world position of the first inner corner
        x_axis: [ax, ay, az]  # unit vector from the first corner along its row
        y_axis: [bx, by, bz]  # unit vector from the first corner down its column
        label: "mark 1"       # optional free text

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

World frame and unit: those of the placements (the paper: millimetres, x
across, y down, z away from the cameras along the middle line).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.board_corners import detect_board_corners
from canopy_stereo.geometry.calibration import (
    TriangulationCheck,
    dlt_projection,
    gold_standard_projection,
)
from canopy_stereo.geometry.camera import camera_centre, project
from canopy_stereo.geometry.chessboard import image_array, image_sequence
from canopy_stereo.geometry.rig import UNIT_TO_METRES, Rig
from canopy_stereo.geometry.triangulation import triangulate_dlt

#: Tolerance on |axis| - 1 and on x_axis . y_axis for a placement's axes.
AXIS_TOLERANCE = 1e-3

#: Keys a placement entry may have.
PLACEMENT_KEYS = ("pair", "origin", "x_axis", "y_axis", "label")


# ----------------------------------------------------------------------------- placements
@dataclass(frozen=True, eq=False)
class BoardPlacement:
    """Where the board stands in one image pair (world frame and unit).

    Attributes:
        pair: index of the image pair in the sorted order of the image globs.
        origin: (3,) world position of the board's first inner corner.
        x_axis: (3,) unit vector from the first corner along its row.
        y_axis: (3,) unit vector from the first corner down its column
            (orthogonal to ``x_axis``).
        label: optional free text (e.g. the mark number on the sheet).
    """

    pair: int
    origin: np.ndarray
    x_axis: np.ndarray
    y_axis: np.ndarray
    label: str = ""

    def __post_init__(self):
        for name in ("origin", "x_axis", "y_axis"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), np.float64).reshape(3))

    @property
    def normal(self) -> np.ndarray:
        """(3,) unit normal ``x_axis x y_axis`` of the board plane."""
        n = np.cross(self.x_axis, self.y_axis)
        return n / np.linalg.norm(n)

    def centre(self, pattern, square: float) -> np.ndarray:
        """(3,) world centre of the inner-corner grid of a ``(cols, rows)`` board."""
        cols, rows = pattern
        return self.origin + square * (0.5 * (cols - 1) * self.x_axis + 0.5 * (rows - 1) * self.y_axis)


@dataclass(frozen=True, eq=False)
class Placements:
    """A board (pattern, square size, unit) and its placements, one per image pair.

    Attributes:
        pattern: ``(cols, rows)`` inner corners.
        square: side of a square in world units.
        unit: world unit (``mm``, ``cm``, ``m``, ``um``, ``in``).
        placements: the :class:`BoardPlacement` s, sorted by ``pair``.
    """

    pattern: tuple[int, int]
    square: float
    unit: str
    placements: tuple

    def __post_init__(self):
        object.__setattr__(self, "pattern", (int(self.pattern[0]), int(self.pattern[1])))
        object.__setattr__(self, "square", float(self.square))
        object.__setattr__(self, "placements", tuple(sorted(self.placements, key=lambda p: p.pair)))
        _check_board(self.pattern, self.square, "placements")
        if self.unit not in UNIT_TO_METRES:
            raise CalibrationError(f"placements: unknown unit {self.unit!r}; expected one of "
                                   f"{', '.join(UNIT_TO_METRES)}")
        pairs = [p.pair for p in self.placements]
        if len(set(pairs)) != len(pairs):
            dup = sorted({p for p in pairs if pairs.count(p) > 1})
            raise CalibrationError(f"placements: pair {dup[0]} is placed more than once")

    def __len__(self) -> int:
        return len(self.placements)

    def __iter__(self):
        return iter(self.placements)

    def __getitem__(self, index):
        return self.placements[index]

    @property
    def pairs(self) -> list[int]:
        """The pair indices that have a placement, ascending."""
        return [p.pair for p in self.placements]

    def by_pair(self) -> dict:
        """``{pair: BoardPlacement}``."""
        return {p.pair: p for p in self.placements}

    def world_points(self, placement: BoardPlacement) -> np.ndarray:
        """(cols*rows, 3) world corners of ``placement`` (see :func:`board_world_points`)."""
        return board_world_points(placement, self.pattern, self.square)

    def subset(self, pairs) -> Placements:
        """The placements of the given pairs, renumbered 0, 1, ... in the given order."""
        by = self.by_pair()
        out = []
        for k, pr in enumerate(pairs):
            if pr not in by:
                raise CalibrationError(f"placements: no placement for pair {pr}")
            p = by[pr]
            out.append(BoardPlacement(k, p.origin, p.x_axis, p.y_axis, p.label))
        return Placements(self.pattern, self.square, self.unit, tuple(out))


def _check_board(pattern, square, where: str) -> None:
    cols, rows = pattern
    if cols < 2 or rows < 2:
        raise CalibrationError(f"{where}: pattern must have at least 2x2 inner corners, got {cols}x{rows}")
    if not (math.isfinite(square) and square > 0):
        raise CalibrationError(f"{where}: square must be a positive number, got {square}")


def parse_pattern(value, where: str = "pattern") -> tuple[int, int]:
    """``"7x5"``, ``[7, 5]`` or ``(7, 5)`` -> ``(7, 5)`` (inner corners, columns x rows)."""
    if isinstance(value, str):
        parts = value.lower().replace(" ", "").split("x")
    elif isinstance(value, (list, tuple)):
        parts = list(value)
    else:
        parts = []
    try:
        if len(parts) != 2:
            raise ValueError
        cols, rows = (int(str(p)) for p in parts)
    except (TypeError, ValueError):
        raise CalibrationError(f"{where} must be COLSxROWS (e.g. 7x5), got {value!r}") from None
    if cols < 2 or rows < 2:
        raise CalibrationError(f"{where} must have at least 2x2 inner corners, got {value!r}")
    return cols, rows


def _vector(value, where: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise CalibrationError(f"{where} must be a list of 3 numbers, got {value!r}")
    try:
        v = np.array([float(x) for x in value])
    except (TypeError, ValueError):
        raise CalibrationError(f"{where} must be a list of 3 numbers, got {value!r}") from None
    if not np.all(np.isfinite(v)):
        raise CalibrationError(f"{where} has non-finite entries")
    return v


def placements_from_dict(doc, source: str = "placements") -> Placements:
    """Validate a parsed placements document (see the module docstring) into :class:`Placements`.

    Raises :class:`~canopy_stereo.errors.CalibrationError` naming ``source``, the
    entry and the problem: missing/unknown keys, a bad pattern or square, an
    unknown unit, vectors that are not 3 numbers, axes that are not unit vectors
    or not orthogonal, duplicate pairs.
    """
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source}: expected a mapping with pattern, square, unit, placements")
    unknown = sorted(set(doc) - {"pattern", "square", "unit", "placements"})
    if unknown:
        raise CalibrationError(f"{source}: unknown key(s) {', '.join(map(str, unknown))} "
                               "(expected pattern, square, unit, placements)")
    for key in ("pattern", "square", "placements"):
        if key not in doc:
            raise CalibrationError(f"{source}: missing '{key}'")
    pattern = parse_pattern(doc["pattern"], f"{source}: pattern")
    try:
        square = float(doc["square"])
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: square must be a number, got {doc['square']!r}") from None
    _check_board(pattern, square, source)
    unit = str(doc.get("unit", "mm"))
    if unit not in UNIT_TO_METRES:
        raise CalibrationError(f"{source}: unknown unit {unit!r}; expected one of {', '.join(UNIT_TO_METRES)}")
    entries = doc["placements"]
    if not isinstance(entries, list) or not entries:
        raise CalibrationError(f"{source}: 'placements' must be a non-empty list")
    out: list = []
    seen: dict = {}
    for k, e in enumerate(entries):
        where = f"{source}: placements[{k}]"
        if not isinstance(e, dict):
            raise CalibrationError(f"{where} must be a mapping with pair, origin, x_axis, y_axis")
        bad = sorted(set(map(str, e)) - set(PLACEMENT_KEYS))
        if bad:
            raise CalibrationError(f"{where}: unknown key(s) {', '.join(bad)} (expected {', '.join(PLACEMENT_KEYS)})")
        missing = [key for key in ("pair", "origin", "x_axis", "y_axis") if key not in e]
        if missing:
            raise CalibrationError(f"{where}: missing {', '.join(missing)}")
        pair = e["pair"]
        if isinstance(pair, bool) or not isinstance(pair, int) or pair < 0:
            raise CalibrationError(f"{where}: pair must be an integer >= 0, got {pair!r}")
        where = f"{source}: placements[{k}] (pair {pair})"
        if pair in seen:
            raise CalibrationError(f"{where}: pair {pair} is already placed by placements[{seen[pair]}]")
        seen[pair] = k
        origin = _vector(e["origin"], f"{where}: origin")
        axes = []
        for name in ("x_axis", "y_axis"):
            v = _vector(e[name], f"{where}: {name}")
            n = float(np.linalg.norm(v))
            if abs(n - 1.0) > AXIS_TOLERANCE:
                raise CalibrationError(f"{where}: {name} must be a unit vector, its length is {n:.4g}")
            axes.append(v / n)
        dot = float(axes[0] @ axes[1])
        if abs(dot) > AXIS_TOLERANCE:
            angle = math.degrees(math.acos(max(-1.0, min(1.0, dot))))
            raise CalibrationError(f"{where}: x_axis and y_axis must be orthogonal, they are "
                                   f"{angle:.2f} degrees apart")
        label = e.get("label", "")
        out.append(BoardPlacement(pair, origin, axes[0], axes[1], "" if label is None else str(label)))
    return Placements(pattern, square, unit, tuple(out))


def board_world_points(placement: BoardPlacement, pattern, square: float) -> np.ndarray:
    """(cols*rows, 3) world coordinates of the inner corners of a board at ``placement``.

    Row-major like OpenCV's ``(cols, rows)`` pattern: index ``j * cols + i`` is
    ``origin + square * (i * x_axis + j * y_axis)`` (world units).
    """
    cols, rows = pattern
    jj, ii = np.mgrid[0:rows, 0:cols]
    return (placement.origin[None, :]
            + square * (ii.reshape(-1, 1) * placement.x_axis[None, :]
                        + jj.reshape(-1, 1) * placement.y_axis[None, :]))


#: Defaults of :func:`paper_layout_placements` (also shown by the CLI).
PAPER_LAYOUT: dict[str, Any] = {
    "angles_deg": (-10.0, 0.0, 10.0),
    "marks_per_line": 15,
    "mark_spacing": 50.0,
    "first_mark": 1000.0,
    "lowest_corner_height": 75.0,
}


def paper_layout_placements(*, pattern=(7, 5), square: float = 50.0, unit: str = "mm",
                            angles_deg=PAPER_LAYOUT["angles_deg"],
                            marks_per_line: int = PAPER_LAYOUT["marks_per_line"],
                            mark_spacing: float = PAPER_LAYOUT["mark_spacing"],
                            first_mark: float = PAPER_LAYOUT["first_mark"],
                            lowest_corner_height: float = PAPER_LAYOUT["lowest_corner_height"]
                            ) -> Placements:
    """The placements of the paper's calibration layout (sec. 2.1, Figures 2-4).

    The floor sheet is the world x-z plane (``y = 0``; x across, y down, z away
    from the cameras, unit ``unit``), with three lines through the origin: the
    middle line along +z and the lines turned by ``angles_deg`` about the
    vertical axis through the origin (the paper: -10 and +10 degrees; a line at
    angle ``a`` runs along ``(sin a, 0, cos a)``). Each line carries
    ``marks_per_line`` marks every ``mark_spacing`` along it, the first at
    ``first_mark`` from the origin; pairs are numbered line by line (the paper's
    marks 1-15 on the -10 degree line, 16-30 on the middle line, 31-45 on the
    +10 degree line), 45 pairs for the defaults.

    At every mark the board stands vertically, centred on the mark and facing
    the origin (its plane perpendicular to the line), rows horizontal and the
    lowest row of inner corners ``lowest_corner_height`` above the sheet. Seen
    from the origin, the first inner corner is the top-left one: ``x_axis``
    runs to the right (``(cos a, 0, -sin a)``) and ``y_axis`` down (``(0, 1, 0)``).

    The paper gives the lines, the spacing and the 50 mm squares but not how far
    from the origin the marks start; the default ``first_mark`` (1000 mm) is the
    nearest at which the whole 7x5 board of 50 mm squares is inside both
    640x480 views of the paper's rig (``config/paper_rig.yaml``) on all three
    lines. Lengths are in ``unit``.

    Returns:
        :class:`Placements` with ``len(angles_deg) * marks_per_line`` placements.
    """
    pattern = parse_pattern(pattern)
    _check_board(pattern, float(square), "paper layout")
    if marks_per_line < 1:
        raise CalibrationError(f"marks_per_line must be >= 1, got {marks_per_line}")
    if not (mark_spacing > 0 and first_mark >= 0 and lowest_corner_height >= 0):
        raise CalibrationError("mark_spacing must be > 0, first_mark and lowest_corner_height >= 0")
    cols, rows = pattern
    out = []
    pair = 0
    for angle in angles_deg:
        a = math.radians(float(angle))
        along = np.array([math.sin(a), 0.0, math.cos(a)])
        x_axis = np.array([math.cos(a), 0.0, -math.sin(a)])
        y_axis = np.array([0.0, 1.0, 0.0])
        for k in range(int(marks_per_line)):
            mark = float(first_mark) + k * float(mark_spacing)
            foot = mark * along
            top = -(float(lowest_corner_height) + (rows - 1) * float(square))
            origin = foot - 0.5 * (cols - 1) * float(square) * x_axis + np.array([0.0, top, 0.0])
            out.append(BoardPlacement(pair, origin, x_axis, y_axis,
                                      f"mark {pair + 1}: line {float(angle):+g} deg, {mark:g} {unit} "
                                      "from the origin"))
            pair += 1
    return Placements(pattern, float(square), unit, tuple(out))


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


# ----------------------------------------------------------------------------- calibration
@dataclass
class WorldRigCalibration:
    """Result of :func:`calibrate_world_rig` (world frame and unit of the placements).

    Attributes:
        rig: the calibrated :class:`~canopy_stereo.geometry.rig.Rig` (no lens distortion:
            the Gold Standard model is linear, as in the paper).
        rms_left, rms_right: reprojection RMS of all used corners, pixels.
        used_pairs: pair indices whose board was found in both images.
        skipped: ``[(pair, reason)]`` pairs left out (board not found, no placement).
        pair_names: ``{pair: (left name, right name)}`` of every image pair.
        orientation_left, orientation_right: ``{pair: symmetry}`` applied to OpenCV's
            corners (``"as detected"``, ``"turned 180 degrees"``, ...).
        placement_rms_left, placement_rms_right: ``{pair: RMS px}`` per used pair.
        world_points: (N, 3) world corners of the used pairs (world units).
        corners_left, corners_right: (N, 2) their detected pixels, in world order.
        point_pair: (N,) pair index of each corner.
        table1: leave-one-placement-out check (the paper's Table 1 and Figure 5):
            every used pair's corners triangulated with the rig calibrated WITHOUT
            that pair; ``errors`` (N, 3) ``X_act - X_est`` and ``distance`` (N,) from
            the midpoint of the camera centres, world units.
        fit_check: the same with the rig fitted on all pairs (optimistic).
    """

    rig: Rig
    rms_left: float
    rms_right: float
    used_pairs: list
    skipped: list
    pair_names: dict
    orientation_left: dict
    orientation_right: dict
    placement_rms_left: dict
    placement_rms_right: dict
    world_points: np.ndarray
    corners_left: np.ndarray
    corners_right: np.ndarray
    point_pair: np.ndarray
    table1: TriangulationCheck
    fit_check: TriangulationCheck
    unit: str = "mm"
    extra: dict = field(default_factory=dict)

    @property
    def P_left(self) -> np.ndarray:
        return self.rig.P_left

    @property
    def P_right(self) -> np.ndarray:
        return self.rig.P_right

    def table(self) -> str:
        """The paper's Table 1 as text (leave-one-placement-out, world units)."""
        u = self.unit
        t = self.table1
        lines = [f"Table 1 (leave-one-placement-out, {len(t.errors)} corners of {len(self.used_pairs)} pairs)",
                 f"axis  mean |X_act - X_est| ({u})  std ({u})  max ({u})"]
        for i, axis in enumerate("XYZ"):
            lines.append(f"{axis:>4}  {t.mean_abs[i]:>24.3f}  {t.std[i]:>9.3f}  {t.max_abs[i]:>8.3f}")
        return "\n".join(lines)

    def summary(self) -> dict:
        """JSON-ready numbers: RMS per camera, Table 1 (mean abs, std of abs, max per axis), pairs."""
        t = self.table1
        return {
            "unit": self.unit,
            "rms_left_px": self.rms_left,
            "rms_right_px": self.rms_right,
            "pairs_used": list(self.used_pairs),
            "pairs_skipped": [{"pair": p, "reason": r} for p, r in self.skipped],
            "table1": {axis: {"mean_abs": float(t.mean_abs[i]), "std": float(t.std[i]),
                              "max_abs": float(t.max_abs[i])} for i, axis in enumerate("XYZ")},
            "corners_reordered": {
                "left": sum(1 for v in self.orientation_left.values() if v != "as detected"),
                "right": sum(1 for v in self.orientation_right.values() if v != "as detected")},
        }


def calibrate_world_rig(left_images, right_images, placements: Placements, *, pattern=None,
                        square: float | None = None, max_rms_px: float = 3.0,
                        leave_one_out: bool = True, detections=None, image_size=None,
                        progress=None) -> WorldRigCalibration:
    """Calibrate both cameras in the placements' world frame from chessboard photographs.

    Corners are detected with sub-pixel refinement in both images of every pair
    (:func:`detect_board_corners`), put into world order
    (:func:`resolve_corner_order`, per camera), given their world coordinates
    from the pair's placement (:func:`board_world_points`), and the Gold
    Standard algorithm (:func:`~canopy_stereo.geometry.calibration.gold_standard_projection`)
    gives ``P_left`` and ``P_right``.

    Args:
        left_images, right_images: sequences of (H, W[, 3]) uint8 arrays (for files:
            :class:`canopy_stereo.io.images.ImageFiles` of a glob, read one pair at a time,
            its file names naming the pairs); pair ``k`` is the k-th left and k-th right image.
        placements: :class:`Placements` (one per pair it covers).
        pattern: ``(cols, rows)`` inner corners; must agree with the placements (default theirs).
        square: square side in world units; must agree with the placements (default theirs).
        max_rms_px: reprojection tolerance (pixels) above which a pair contradicts its placement.
        leave_one_out: compute Table 1 leave-one-placement-out (else ``table1`` is the fit check).
        detections: optional precomputed ``{pair: (left (M, 2) | None, right (M, 2) | None)}``
            corners in OpenCV's (any) order, instead of detecting them in the images
            (the images may then be None).
        image_size: ``(width, height)`` written to the rig when no image is read
            (default: the images' size).
        progress: optional callable ``progress(message)``.

    Returns:
        :class:`WorldRigCalibration`.

    Raises:
        CalibrationError: pattern/square disagree with the placements; left and right
            counts or image sizes differ; a placement names a pair that has no images;
            the board is found in fewer than 3 pairs; a pair contradicts its placement.
    """
    say = progress or (lambda _m: None)
    pat = placements.pattern if pattern is None else parse_pattern(pattern)
    if pat != placements.pattern:
        raise CalibrationError(f"pattern {pat[0]}x{pat[1]} does not match the placements' "
                               f"{placements.pattern[0]}x{placements.pattern[1]}")
    sq = placements.square if square is None else float(square)
    if abs(sq - placements.square) > 1e-9 * max(1.0, abs(sq)):
        raise CalibrationError(f"square {sq:g} does not match the placements' {placements.square:g}")
    lefts, left_names = image_sequence(left_images, "left")
    rights, right_names = image_sequence(right_images, "right")
    if len(lefts) != len(rights):
        raise CalibrationError(f"{len(lefts)} left images but {len(rights)} right images")
    n_pairs = len(lefts)
    by_pair = placements.by_pair()
    beyond = [p for p in by_pair if p >= n_pairs]
    if beyond:
        raise CalibrationError(f"the placements place pair {beyond[0]} but there are only {n_pairs} "
                               f"image pairs (0..{n_pairs - 1})")
    skipped, names, used = [], {}, []
    det_l, det_r = {}, {}
    size = None
    for k in range(n_pairs):
        ln, rn = left_names[k], right_names[k]
        names[k] = (ln, rn)
        if k not in by_pair:
            skipped.append((k, "no placement"))
            continue
        if detections is not None and k in detections:
            cl, cr = detections[k]
        else:
            gl, gr = image_array(lefts[k], ln), image_array(rights[k], rn)
            if gl.shape[:2] != gr.shape[:2]:
                raise CalibrationError(f"pair {k}: {ln} and {rn} differ in size")
            this = (gl.shape[1], gl.shape[0])
            if size is None:
                size = this
            elif size != this:
                raise CalibrationError(f"pair {k}: {ln} is {this[0]}x{this[1]}, expected {size[0]}x{size[1]}")
            cl, cr = detect_board_corners(gl, pat), detect_board_corners(gr, pat)
        if cl is None or cr is None:
            where = "either image" if cl is None and cr is None else ("the left image" if cl is None
                                                                       else "the right image")
            skipped.append((k, f"board not found in {where}"))
            say(f"pair {k} ({ln}, {rn}): board not found in {where}, skipped")
            continue
        det_l[k], det_r[k] = np.asarray(cl, np.float64), np.asarray(cr, np.float64)
        used.append(k)
    if image_size is not None:
        image_size = (int(image_size[0]), int(image_size[1]))
        if size is not None and size != image_size:
            raise CalibrationError(f"the images are {size[0]}x{size[1]}, not {image_size[0]}x{image_size[1]}")
        size = image_size
    if size is None:
        for k in range(len(lefts)):
            item = lefts[k]
            if item is not None and np.ndim(item) >= 2:
                size = (np.shape(item)[1], np.shape(item)[0])
                break
    if size is None:
        raise CalibrationError("image_size is needed when no image is given")
    if len(used) < 3:
        raise CalibrationError(
            f"the {pat[0]}x{pat[1]} board was found in both images of only {len(used)} pair(s); need at "
            "least 3 (check --pattern: inner corners, columns x rows)")
    say(f"board found in {len(used)} of {n_pairs} pairs; resolving the corner order")
    W = [board_world_points(by_pair[k], pat, sq) for k in used]
    vnames = [f"pair {k} ({names[k][0]}, {names[k][1]})" for k in used]
    ord_l = resolve_corner_order(W, [det_l[k] for k in used], pat, max_rms_px=max_rms_px,
                                 view_names=[v + " left" for v in vnames])
    ord_r = resolve_corner_order(W, [det_r[k] for k in used], pat, max_rms_px=max_rms_px,
                                 view_names=[v + " right" for v in vnames])
    XL = [det_l[k][ord_l.index[i]] for i, k in enumerate(used)]
    XR = [det_r[k][ord_r.index[i]] for i, k in enumerate(used)]
    X = np.vstack(W)
    xl, xr = np.vstack(XL), np.vstack(XR)
    point_pair = np.repeat(np.array(used), pat[0] * pat[1])
    say("Gold Standard calibration of both cameras")
    P_l, rms_l = gold_standard_projection(X, xl)
    P_r, rms_r = gold_standard_projection(X, xr)
    rig = Rig(P_left=P_l, P_right=P_r, image_size=size, world_unit=placements.unit)
    mid = 0.5 * (camera_centre(P_l) + camera_centre(P_r))
    dist = np.linalg.norm(X - mid, axis=1)
    fit = TriangulationCheck(errors=X - triangulate_dlt(P_l, P_r, xl, xr, drop_behind=False), distance=dist)
    if leave_one_out:
        errs = np.empty_like(X)
        for i, k in enumerate(used):
            if i % 10 == 0 or i == len(used) - 1:
                say(f"leave-one-placement-out: pair {k} ({i + 1}/{len(used)})")
            keep = point_pair != k
            Pl_i, _ = gold_standard_projection(X[keep], xl[keep], initial=P_l)
            Pr_i, _ = gold_standard_projection(X[keep], xr[keep], initial=P_r)
            sel = ~keep
            errs[sel] = X[sel] - triangulate_dlt(Pl_i, Pr_i, xl[sel], xr[sel], drop_behind=False)
        table1 = TriangulationCheck(errors=errs, distance=dist)
    else:
        table1 = fit
    per_l = {k: float(np.sqrt(np.mean(np.sum((project(P_l, W[i]) - XL[i]) ** 2, axis=1))))
             for i, k in enumerate(used)}
    per_r = {k: float(np.sqrt(np.mean(np.sum((project(P_r, W[i]) - XR[i]) ** 2, axis=1))))
             for i, k in enumerate(used)}
    return WorldRigCalibration(
        rig=rig, rms_left=float(rms_l), rms_right=float(rms_r), used_pairs=used, skipped=skipped,
        pair_names=names, orientation_left={k: ord_l.names[i] for i, k in enumerate(used)},
        orientation_right={k: ord_r.names[i] for i, k in enumerate(used)},
        placement_rms_left=per_l, placement_rms_right=per_r, world_points=X, corners_left=xl,
        corners_right=xr, point_pair=point_pair, table1=table1, fit_check=fit, unit=placements.unit)


def plot_world_rig_errors(calibration: WorldRigCalibration, path) -> Path:
    """The paper's Figure 5 (error in X, Y and Z against distance from the rig) as a PNG.

    Uses the leave-one-placement-out errors of ``calibration.table1``.
    """
    from canopy_stereo.geometry.chessboard import plot_triangulation_errors

    plot_triangulation_errors(calibration.table1, path, unit=calibration.unit)
    return Path(path)
