"""Where a chessboard stood in each image pair of a world-rig calibration, and the world
coordinates of its corners (paper sec. 2.1).

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

World frame and unit: those of the placements (the paper: millimetres, x across, y down, z
away from the cameras along the middle line).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.rig import UNIT_TO_METRES

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
