"""The result of matching one stereo pair with one method (one row of the study table)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Side of the square cells of the distribution measure, in pixels (Ni & Burks, sec. 2.2).
DISTRIBUTION_CELL_PX = 8


def distribution(x_left: np.ndarray, image_size, *, cell_px: int = DISTRIBUTION_CELL_PX) -> float:
    """Share of ``cell_px`` x ``cell_px``-pixel cells of the left image holding a matched point.

    The paper's definition: the left image is divided into square cells of 8 x 8
    pixels, a cell is *used* when at least one matched point falls in it, and the
    distribution is ``used cells / all cells`` (a fraction in [0, 1]; the paper
    prints it in per cent). A 640x480 image has 80 x 60 = 4800 cells; the last
    column/row of cells is partial when the size is not a multiple of ``cell_px``
    and still counts as one cell.

    Pixel ``i`` covers ``[i - 0.5, i + 0.5)``, so cell ``k`` holds the points with
    ``8k - 0.5 <= u < 8k + 7.5``. Points outside the image are ignored.

    Args:
        x_left: (N, 2) left-image points ``(u, v)`` in pixels.
        image_size: ``(width, height)`` of the left image in pixels.
        cell_px: cell side in pixels.
    """
    w, h = int(image_size[0]), int(image_size[1])
    if w <= 0 or h <= 0 or cell_px <= 0:
        raise ValueError(f"image_size {image_size} and cell_px {cell_px} must be positive")
    nx, ny = -(-w // cell_px), -(-h // cell_px)
    x = np.asarray(x_left, dtype=np.float64).reshape(-1, 2)
    inside = (x[:, 0] >= -0.5) & (x[:, 0] < w - 0.5) & (x[:, 1] >= -0.5) & (x[:, 1] < h - 0.5)
    x = x[inside]
    cx = np.floor((x[:, 0] + 0.5) / cell_px).astype(np.int64)
    cy = np.floor((x[:, 1] + 0.5) / cell_px).astype(np.int64)
    used = np.zeros((ny, nx), dtype=bool)
    used[cy, cx] = True
    return float(used.sum()) / float(nx * ny)


@dataclass
class MatchResult:
    """Verified correspondences of a stereo pair and the cost of finding them.

    Coordinates are pixels of the ORIGINAL images given to the matcher
    (``u`` right, ``v`` down, top-left pixel centre at (0, 0)).

    Attributes:
        method: matcher name (``"sift"``, ``"qdmatch"``, ...).
        x_left, x_right: (N, 2) float64 matched points; row i of each is one match.
        image_size: ``(width, height)`` of the left image.
        num_left, num_right: features detected in the left/right image (the
            paper's num1/num2; for qdmatch the SIFT seeds' keypoints).
        t_left, t_right: detection (+ description) time of the left/right image,
            seconds (the paper's t1/t2).
        t_match: descriptor matching + geometric verification time, seconds (t).
        t_propagation, t_resample: quasi-dense propagation and resampling times,
            seconds; ``None`` for the sparse methods.
        F: (3, 3) fundamental matrix from the verification (``x_r^T F x_l = 0``),
            or ``None`` when too few matches remained to estimate one.
        note: why a row is empty or unusual (e.g. "SURF is patented ..."), else "".
        extras: method-specific counts (e.g. ``num_seeds``, ``num_propagated``).
    """

    method: str
    x_left: np.ndarray
    x_right: np.ndarray
    image_size: tuple
    num_left: int = 0
    num_right: int = 0
    t_left: float = 0.0
    t_right: float = 0.0
    t_match: float = 0.0
    t_propagation: float | None = None
    t_resample: float | None = None
    F: np.ndarray | None = None
    note: str = ""
    extras: dict = field(default_factory=dict)

    def __post_init__(self):
        self.x_left = np.asarray(self.x_left, dtype=np.float64).reshape(-1, 2)
        self.x_right = np.asarray(self.x_right, dtype=np.float64).reshape(-1, 2)
        if len(self.x_left) != len(self.x_right):
            raise ValueError("x_left and x_right must hold the same number of points")
        self.image_size = (int(self.image_size[0]), int(self.image_size[1]))

    @property
    def num(self) -> int:
        """Number of verified matches (the paper's num)."""
        return int(len(self.x_left))

    @property
    def distribution(self) -> float:
        """Share of 8 x 8-pixel left-image cells holding a match, in [0, 1]."""
        return distribution(self.x_left, self.image_size)

    @property
    def t_total(self) -> float:
        """All stages together, seconds."""
        return (self.t_left + self.t_right + self.t_match + (self.t_propagation or 0.0)
                + (self.t_resample or 0.0))

    @classmethod
    def empty(cls, method: str, image_size, *, note: str = "", **kw) -> MatchResult:
        """A result without matches (an empty table row), e.g. for an unavailable method."""
        return cls(method=method, x_left=np.zeros((0, 2)), x_right=np.zeros((0, 2)),
                   image_size=image_size, note=note, **kw)
