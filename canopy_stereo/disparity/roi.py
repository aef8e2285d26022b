"""Disparity only where the plant is: the matching window of a frame from the previous masks.

When the cloud keeps only plant pixels anyway, matching the whole frame is wasted work.
:class:`RoiPlanner` turns the plant masks of the previous frames (uint8 (H, W), 0 =
background) into the :class:`MatchWindow` of the next pair: the plant's bounding box,
dilated by ``margin`` pixels (plant motion between frames and the matcher's support
neighbourhood), aligned to :data:`ALIGN` pixels, with the columns the disparity search
needs; :func:`disparity_in_window` matches the pair only there and returns a full-size map,
invalid (-1) outside the window. The planner falls back to the full frame (``plan`` returns
``None`` with the reason) on the first frame, when the masks stop, every ``full_every``
frames (so that plants appearing anywhere are found), and on a cut: the last mask is empty,
its plant area jumped by more than ``max_area_change``, or the plant reaches the border of
the window its own frame was matched in (a plant entering, or motion beyond the margin).
A window covering more than ``max_share`` of the frame is matched as the full frame.

Columns: left pixel ``u`` matches right pixel ``u - d`` for ``d`` in ``[disp_min, disp_max]``.
The window crops the left image to ``[xa, xb)`` and the right image to ``[xa - shift,
xb - shift)`` with ``shift`` = ``disp_min`` rounded down to :data:`ALIGN` and ``xa = x0 -
BORDER - (disp_max - shift)``, and searches ``[disp_min - shift, disp_max - shift]`` there:
every kept left pixel (``u >= x0``) sees its whole search range, as in the full frame (a kept
pixel nearer the left image border than ``disp_max`` sees what it sees in the full frame, no
more). Rows are cropped alike in both images (rectified: matches lie on the same row), and
the crop extends :data:`BORDER` pixels beyond the kept box, where ELAS leaves its border.
ELAS on a crop is not bit-identical to ELAS on the frame (support points near the crop's edge,
the Delaunay mesh over them and the gap interpolation see less of the image): with every
corner and the shift on :data:`ALIGN`, 72-97 % of the plant pixels get the same disparity and
more than 99.9 % agree within 1 px (``test/disparity/test_roi.py``, ``benchmarks/bench_roi.py``).

All coordinates are rectified pixels; boxes are half-open ``(x0, y0, x1, y1)``.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from canopy_stereo.disparity.registry import INVALID_DISPARITY, compute_disparity
from canopy_stereo.errors import CanopyStereoError

#: Window corners are multiples of this (pixels): ELAS's support-candidate step (5), its grid
#: cells (20) and subsampling (2) fall on the same pixels as in the full frame.
ALIGN = 20
#: Pixels the crop extends beyond the kept box: ELAS leaves a border of its image invalid
#: (its descriptor and matching windows), a multiple of :data:`ALIGN`.
BORDER = ALIGN
#: Defaults of :class:`RoiPlanner` (the node's ``roi_*`` parameters).
DEFAULT_MARGIN = 32
DEFAULT_FULL_EVERY = 30
DEFAULT_MAX_SHARE = 0.8
#: Relative change of the plant area between two masks beyond which the scene is cut.
MAX_AREA_CHANGE = 0.3
#: Frames matched without a newer mask before the masks count as stopped (full frame).
MAX_MASK_AGE = 5
#: Windows remembered by stamp (to check the plant against its own frame's window).
WINDOWS_KEPT = 64


@dataclass(frozen=True)
class MatchWindow:
    """Where a pair is matched (rectified pixels).

    Attributes:
        x0, y0, x1, y1: the kept box of the left image (half-open); disparities outside it
            are invalid.
        xa, ya, xb, yb: the crop of the left image given to the matcher (half-open, holding
            the kept box): :data:`BORDER` more pixels on every side (the matcher leaves its
            image border invalid) and ``disp_max - shift`` more on the left (the search's context).
        shift: the right image is cropped ``shift`` columns left of the left crop; the
            matcher searches ``d - shift``.
        match_from: left columns before it have no match in the full frame either
            (``u < disp_min``).
        image_size: ``(width, height)`` of the full frame.
    """

    x0: int
    y0: int
    x1: int
    y1: int
    xa: int
    ya: int
    xb: int
    yb: int
    shift: int
    match_from: int
    image_size: tuple[int, int]

    @property
    def box(self) -> tuple[int, int, int, int]:
        """The kept box ``(x0, y0, x1, y1)``."""
        return self.x0, self.y0, self.x1, self.y1

    @property
    def matched_share(self) -> float:
        """Share of the frame's pixels given to the matcher (crop area / frame area)."""
        w, h = self.image_size
        return (self.xb - self.xa) * (self.yb - self.ya) / float(w * h)


def plant_box(mask: np.ndarray) -> tuple[tuple[int, int, int, int] | None, float]:
    """``(box, share)`` of a plant mask (uint8 (H, W), nonzero = plant): the half-open
    bounding box ``(x0, y0, x1, y1)`` of its plant pixels (None when there are none) and
    the plant's share of the image's pixels."""
    m = np.asarray(mask)
    if m.ndim != 2 or m.size == 0:
        raise CanopyStereoError(f"a plant mask must be a non-empty (H, W) array, got shape {m.shape}")
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        return None, 0.0
    cols = np.flatnonzero(m[rows[0]:rows[-1] + 1].any(axis=0))
    share = float(np.count_nonzero(m[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1])) / m.size
    return (int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1), share


def match_window(box, *, image_size, disp_min: int, disp_max: int, margin: int = DEFAULT_MARGIN,
                 max_share: float = DEFAULT_MAX_SHARE) -> MatchWindow | None:
    """The :class:`MatchWindow` of a plant ``box`` ``(x0, y0, x1, y1)`` dilated by ``margin``
    pixels and aligned to :data:`ALIGN`, in a frame of ``image_size`` ``(width, height)``,
    for the search range ``disp_min``..``disp_max`` (pixels); None (match the full frame)
    when the matched crop would cover more than ``max_share`` of the frame."""
    w, h = (int(v) for v in image_size)
    x0, y0, x1, y1 = (int(v) for v in box)
    m = max(0, int(margin))
    x0, y0 = max(0, (x0 - m) // ALIGN * ALIGN), max(0, (y0 - m) // ALIGN * ALIGN)
    x1, y1 = min(w, -(-(x1 + m) // ALIGN) * ALIGN), min(h, -(-(y1 + m) // ALIGN) * ALIGN)
    if x1 <= x0 or y1 <= y0:
        return None
    # a multiple of ALIGN, so that the right crop's support candidates fall on the full frame's too
    shift = max(int(disp_min), 0) // ALIGN * ALIGN
    # the matcher's own border (invalid) lies outside the kept box
    ya, yb, xb = max(0, y0 - BORDER), min(h, y1 + BORDER), min(w, x1 + BORDER)
    xa = max(shift, x0 - BORDER - (int(disp_max) - shift))  # the right crop starts at xa - shift >= 0
    if xa // ALIGN * ALIGN >= shift:
        xa = xa // ALIGN * ALIGN
    x0 = max(x0, xa)  # left pixels u < disp_min have no match in the full frame either
    # the matcher needs more columns than disparities searched (ELAS caps the range at w - 1)
    if xb - xa <= int(disp_max) - shift or x1 <= x0:
        return None
    window = MatchWindow(x0, y0, x1, y1, xa, ya, xb, yb, shift, max(int(disp_min), 0), (w, h))
    return None if window.matched_share > float(max_share) else window


def disparity_in_window(left: np.ndarray, right: np.ndarray, window: MatchWindow, *, matcher: str,
                        disp_min: int, disp_max: int, **params) -> np.ndarray:
    """Left disparity (float32 (H, W), pixels, invalid = -1) of a rectified pair matched only
    in ``window`` (:func:`~canopy_stereo.disparity.compute_disparity` on the crops, the
    search shifted by ``window.shift``); -1 outside the window's kept box."""
    h, w = left.shape[:2]
    if (w, h) != tuple(window.image_size) or right.shape[:2] != left.shape[:2]:
        raise CanopyStereoError(f"the window is for {window.image_size[0]}x{window.image_size[1]} frames, "
                                f"the pair is {w}x{h} and {right.shape[1]}x{right.shape[0]}")
    s, rows = window.shift, slice(window.ya, window.yb)
    crop = compute_disparity(left[rows, window.xa:window.xb], right[rows, window.xa - s:window.xb - s],
                             matcher=matcher, disp_min=int(disp_min) - s, disp_max=int(disp_max) - s,
                             **params)
    out = np.full((h, w), INVALID_DISPARITY, np.float32)
    kept = crop[window.y0 - window.ya:window.y1 - window.ya, window.x0 - window.xa:window.x1 - window.xa]
    out[window.y0:window.y1, window.x0:window.x1] = np.where(kept >= 0, kept + np.float32(s),
                                                             np.float32(INVALID_DISPARITY))
    return out


class RoiPlanner:
    """The matching window of each pair from the masks of the previous frames (module docstring).

    Keyword args:
        margin: dilation of the plant's box (pixels, >= 0).
        full_every: a full frame at least every this many frames (>= 1; 1 = always full).
        max_share: windows covering more of the frame are matched as the full frame (0..1].
        max_area_change: relative change of the plant area between masks that counts as a cut.

    Thread-safe use is the caller's: the node calls :meth:`observe` and :meth:`plan` under one lock.
    """

    def __init__(self, *, margin: int = DEFAULT_MARGIN, full_every: int = DEFAULT_FULL_EVERY,
                 max_share: float = DEFAULT_MAX_SHARE, max_area_change: float = MAX_AREA_CHANGE):
        if int(margin) < 0 or int(full_every) < 1 or not 0 < float(max_share) <= 1:
            raise CanopyStereoError(f"RoiPlanner needs margin >= 0, full_every >= 1 and 0 < max_share <= 1, got "
                                    f"{margin}, {full_every}, {max_share}")
        self.margin, self.full_every = int(margin), int(full_every)
        self.max_share, self.max_area_change = float(max_share), float(max_area_change)
        self._windows: OrderedDict[int, MatchWindow | None] = OrderedDict()
        self._mask: tuple | None = None  # (stamp_ns, box, share, reason for a cut or None)
        self._previous_share: float | None = None
        self._since_full = 0
        self._since_mask = 0

    def observe(self, stamp_ns: int, mask: np.ndarray) -> None:
        """The plant mask of the frame stamped ``stamp_ns`` (uint8 (H, W), nonzero = plant).
        Masks older than the newest one seen are ignored."""
        if self._mask is not None and int(stamp_ns) <= self._mask[0]:
            return
        box, share = plant_box(mask)
        cut = None
        if box is None:
            cut = "no plant in the last mask"
        elif self._previous_share and abs(share - self._previous_share) > self.max_area_change * self._previous_share:
            cut = "the plant area jumped between masks"
        else:
            window = self._windows.get(int(stamp_ns))
            if window is not None and _touches(box, window):
                cut = "the plant reaches the border of the window its frame was matched in"
        self._previous_share = share
        self._mask = (int(stamp_ns), box, share, cut)
        self._since_mask = 0

    def plan(self, stamp_ns: int, *, image_size, disp_min: int, disp_max: int) -> tuple[MatchWindow | None, str]:
        """``(window, reason)`` for the pair stamped ``stamp_ns``: a :class:`MatchWindow`, or None
        for the full frame with the reason (``reason`` is "" for a window)."""
        window, reason = None, ""
        mask = self._mask
        if mask is None:
            reason = "no mask yet"
        elif self._since_mask >= MAX_MASK_AGE:
            reason = f"no new mask for {self._since_mask} frames"
        elif self._since_full >= self.full_every:
            reason = f"periodic full frame (every {self.full_every})"
        elif mask[3] is not None:
            reason = mask[3]
        elif mask[1] is None:
            reason = "no plant in the last mask"
        else:
            window = match_window(mask[1], image_size=image_size, disp_min=disp_min, disp_max=disp_max,
                                  margin=self.margin, max_share=self.max_share)
            reason = "" if window is not None else f"the window would cover more than {self.max_share:.0%}"
        if mask is not None and mask[3] is not None and window is None:
            # a cut is answered once: the full frame's mask decides the next window
            self._mask = (mask[0], mask[1], mask[2], None)
        self._since_full = 0 if window is None else self._since_full + 1
        self._since_mask += 1
        self._windows[int(stamp_ns)] = window
        while len(self._windows) > WINDOWS_KEPT:
            self._windows.popitem(last=False)
        return window, reason


def _touches(box, window: MatchWindow) -> bool:
    """Whether a plant ``box`` reaches an edge of ``window``'s kept box that is not the image border
    (nor, on the left, the columns that have no match in the full frame either)."""
    x0, y0, x1, y1 = box
    w, h = window.image_size
    return ((window.x0 > window.match_from and x0 <= window.x0) or (window.y0 > 0 and y0 <= window.y0)
            or (window.x1 < w and x1 >= window.x1) or (window.y1 < h and y1 >= window.y1))
