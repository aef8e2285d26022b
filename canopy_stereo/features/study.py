"""The feature-matching study (Ni & Burks, Tables 2-4) as a rerunnable tool.

For one stereo pair every method gives one row: t1, num1, t2, num2, t (matching),
propagation, resample, num (matches) and distribution, plus a correctness figure
the paper could not give:

* with a ground-truth disparity of a rectified pair: the share of matches whose
  disparity ``u_left - u_right`` is within 1 px of the truth at the left point
  (nearest pixel) and whose rows differ by at most 1 px (Middlebury's "bad 1.0"
  criterion); matches on pixels without truth are left out of the share;
* with exact correspondences (a rendered scene, rectified or not): the share of
  matches within 1 px (each coordinate) of the true right pixel;
* without either: the share of matches within 1 px of the epipolar line (in the
  right image) of an F fitted by RANSAC to all methods' verified matches pooled.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError, MatchingError
from canopy_stereo.features.api import METHODS, check_method, match_pair, method_available
from canopy_stereo.features.result import MatchResult
from canopy_stereo.geometry.fundamental import MIN_MATCHES_F, epipolar_distance, estimate_fundamental

#: Methods of the ``features`` command when none are named (the issue's list plus SURF,
#: whose row says why it is absent).
DEFAULT_METHODS = ("harris-affine", "hessian-affine", "sift", "asift", "surf", "orb", "akaze",
                   "qdmatch")

#: Correctness tolerance, pixels.
CORRECT_TOL_PX = 1.0


@dataclass
class StudyRow:
    """One line of the table: a :class:`MatchResult` and its correctness.

    Attributes:
        result: the matches and timings.
        correct: share (0..1) of matches within 1 px of the truth / the epipolar
            line, or None when it cannot be computed (no matches, no reference).
        correct_basis: ``"gt"`` or ``"epipolar"`` (what ``correct`` measures).
        n_evaluated: matches that entered ``correct`` (those with known truth).
    """

    result: MatchResult
    correct: float | None = None
    correct_basis: str = ""
    n_evaluated: int = 0


def parse_methods(text: str) -> list[str]:
    """``"sift,qdmatch"`` -> ``["sift", "qdmatch"]``; unknown names raise :class:`CanopyStereoError`."""
    names = [m.strip().lower() for m in str(text).split(",") if m.strip()]
    if not names:
        raise CanopyStereoError("no matching method named")
    for m in names:
        check_method(m)
    return list(dict.fromkeys(names))


def gt_correctness(x_left, x_right, disparity: np.ndarray, *, tol_px: float = CORRECT_TOL_PX):
    """Share of matches consistent with a ground-truth disparity map: ``(share, n_with_truth)``.

    A match ``(u, v) <-> (u', v')`` of a rectified pair is correct when
    ``|(u - u') - d(round(v), round(u))| <= tol_px`` and ``|v' - v| <= tol_px``.
    ``disparity`` is float (H, W), NaN (or non-finite) where unknown. Returns
    ``(None, 0)`` when no match lands on a known disparity.
    """
    xl = np.asarray(x_left, np.float64).reshape(-1, 2)
    xr = np.asarray(x_right, np.float64).reshape(-1, 2)
    d = np.asarray(disparity, np.float64)
    h, w = d.shape[:2]
    u = np.rint(xl[:, 0]).astype(np.int64)
    v = np.rint(xl[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    truth = np.full(len(xl), np.nan)
    truth[inside] = d[v[inside], u[inside]]
    known = np.isfinite(truth)
    n = int(known.sum())
    if n == 0:
        return None, 0
    err_d = np.abs((xl[known, 0] - xr[known, 0]) - truth[known])
    err_v = np.abs(xr[known, 1] - xl[known, 1])
    return float(np.mean((err_d <= tol_px) & (err_v <= tol_px))), n


def correspondence_correctness(x_left, x_right, true_right: np.ndarray,
                               *, tol_px: float = CORRECT_TOL_PX):
    """Share of matches within ``tol_px`` of the true right pixel: ``(share, n_with_truth)``.

    For pairs whose exact correspondences are known (rendered scenes, any geometry,
    rectified or not): match ``(u, v) <-> (u', v')`` is correct when both coordinates
    of ``(u', v')`` are within ``tol_px`` of ``true_right[round(v), round(u)]``.
    ``true_right`` is float (H, W, 2), NaN where the left pixel has no
    correspondence (see :func:`canopy_stereo.sim.correspondence.true_right_pixels`).
    Returns ``(None, 0)`` when no match lands on a pixel with truth.
    """
    xl = np.asarray(x_left, np.float64).reshape(-1, 2)
    xr = np.asarray(x_right, np.float64).reshape(-1, 2)
    t = np.asarray(true_right, np.float64)
    if t.ndim != 3 or t.shape[2] != 2:
        raise CanopyStereoError(f"true right pixels must be (H, W, 2), got {t.shape}")
    h, w = t.shape[:2]
    u = np.rint(xl[:, 0]).astype(np.int64)
    v = np.rint(xl[:, 1]).astype(np.int64)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    truth = np.full((len(xl), 2), np.nan)
    truth[inside] = t[v[inside], u[inside]]
    known = np.all(np.isfinite(truth), axis=1)
    n = int(known.sum())
    if n == 0:
        return None, 0
    err = np.abs(xr[known] - truth[known]).max(axis=1)
    return float(np.mean(err <= tol_px)), n


def epipolar_correctness(results, threshold_px: float = CORRECT_TOL_PX, *, f_method: str = "ransac"):
    """Per result, the share of matches within ``threshold_px`` of the epipolar line of
    one F fitted to all results' matches pooled: ``(shares list, F or None)``."""
    xl = [r.x_left for r in results if r.num]
    xr = [r.x_right for r in results if r.num]
    if not xl or sum(len(a) for a in xl) < MIN_MATCHES_F:
        return [None] * len(results), None
    try:
        F, _ = estimate_fundamental(np.vstack(xl), np.vstack(xr), method=f_method,
                                    threshold_px=threshold_px)
    except MatchingError:
        return [None] * len(results), None
    shares = []
    for r in results:
        if r.num == 0:
            shares.append(None)
            continue
        shares.append(float(np.mean(epipolar_distance(F, r.x_left, r.x_right) <= threshold_px)))
    return shares, F


def run_study(left: np.ndarray, right: np.ndarray, *, methods=DEFAULT_METHODS,
              gt_disparity: np.ndarray | None = None, method_params: dict | None = None,
              progress=None, gt_right_pixels: np.ndarray | None = None) -> list[StudyRow]:
    """Match one pair with every method and score the rows.

    Args:
        left, right: uint8 images (grey or BGR) of the same size.
        methods: method names (see :data:`~canopy_stereo.features.METHODS`).
        gt_disparity: optional float (H, W) truth of a rectified pair (NaN unknown).
        gt_right_pixels: optional float (H, W, 2) true right pixel of each left pixel
            (NaN unknown), for pairs of any geometry with exact correspondences
            (rendered scenes); scored by :func:`correspondence_correctness`.
        method_params: ``{method: {param: value}}`` passed to :func:`match_pair`.
        progress: optional callable(method) called before each method runs.

    Returns:
        One :class:`StudyRow` per method, in the given order. A method that is not
        available here, or that finds nothing (e.g. no texture), gives an empty row
        whose ``result.note`` says why; bad images (different sizes, not uint8) raise.
    """
    methods = [check_method(m) for m in methods]
    left, right = np.asarray(left), np.asarray(right)
    if gt_disparity is not None:
        gt_disparity = np.asarray(gt_disparity, np.float64)
        if gt_disparity.shape[:2] != left.shape[:2]:
            raise ImageError(f"ground truth is {gt_disparity.shape[1]}x{gt_disparity.shape[0]} "
                             f"but the images are {left.shape[1]}x{left.shape[0]}")
    if gt_disparity is not None and gt_right_pixels is not None:
        raise CanopyStereoError("give either a ground-truth disparity or true right pixels, not both")
    if gt_right_pixels is not None:
        gt_right_pixels = np.asarray(gt_right_pixels, np.float64)
        if gt_right_pixels.shape[:2] != left.shape[:2]:
            raise ImageError(f"true right pixels are {gt_right_pixels.shape[1]}x"
                             f"{gt_right_pixels.shape[0]} but the images are "
                             f"{left.shape[1]}x{left.shape[0]}")
    size = (left.shape[1], left.shape[0])
    params = method_params or {}
    results = []
    for m in methods:
        if progress is not None:
            progress(m)
        ok, reason = method_available(m)
        if not ok:
            results.append(MatchResult.empty(m, size, note=reason))
            continue
        try:
            results.append(match_pair(left, right, method=m, min_matches=0, **params.get(m, {})))
        except ImageError:
            raise
        except MatchingError as exc:
            results.append(MatchResult.empty(m, size, note=str(exc)))
    rows = []
    if gt_disparity is not None:
        for r in results:
            share, n = gt_correctness(r.x_left, r.x_right, gt_disparity)
            rows.append(StudyRow(r, share, "gt", n))
    elif gt_right_pixels is not None:
        for r in results:
            share, n = correspondence_correctness(r.x_left, r.x_right, gt_right_pixels)
            rows.append(StudyRow(r, share, "gt", n))
    else:
        shares, _ = epipolar_correctness(results)
        for r, share in zip(results, shares):
            rows.append(StudyRow(r, share, "epipolar", r.num if share is not None else 0))
    return rows


# ----------------------------------------------------------------------------- output

COLUMNS = ("method", "t1_s", "num1", "t2_s", "num2", "t_s", "propagation_s", "resample_s", "num",
           "distribution_pct", "correct_pct", "correct_basis", "note")


def row_values(row: StudyRow) -> dict:
    """The table columns of a row as a dict (numbers; None for "/" cells)."""
    r = row.result
    return {
        "method": r.method,
        "t1_s": r.t_left, "num1": r.num_left, "t2_s": r.t_right, "num2": r.num_right,
        "t_s": r.t_match, "propagation_s": r.t_propagation, "resample_s": r.t_resample,
        "num": r.num, "distribution_pct": 100.0 * r.distribution,
        "correct_pct": None if row.correct is None else 100.0 * row.correct,
        "correct_basis": row.correct_basis, "note": r.note,
    }


def format_table(rows: list[StudyRow]) -> str:
    """The study as fixed-width text, the paper's columns plus the correctness column."""
    basis = next((r.correct_basis for r in rows if r.correct_basis), "gt")
    corr_head = "<=1px GT" if basis == "gt" else "<=1px epi"
    head = (f"{'method':<15}{'t1 (s)':>8}{'num1':>8}{'t2 (s)':>8}{'num2':>8}{'t (s)':>8}"
            f"{'prop (s)':>9}{'resamp (s)':>11}{'num':>7}{'distrib':>9}{corr_head:>11}")
    lines = [head, "-" * len(head)]
    notes = []
    for row in rows:
        v = row_values(row)
        r = row.result

        def t(x):
            return "/" if x is None else f"{x:.2f}"

        empty = r.num == 0 and r.num_left == 0 and r.num_right == 0 and r.t_total == 0.0
        if empty:
            line = f"{v['method']:<15}" + f"{'-':>8}" * 5 + f"{'-':>9}{'-':>11}{0:>7}{'-':>9}{'-':>11}"
        else:
            corr = "-" if v["correct_pct"] is None else f"{v['correct_pct']:.1f}%"
            line = (f"{v['method']:<15}{t(v['t1_s']):>8}{v['num1']:>8}{t(v['t2_s']):>8}{v['num2']:>8}"
                    f"{t(v['t_s']):>8}{t(v['propagation_s']):>9}{t(v['resample_s']):>11}{v['num']:>7}"
                    f"{v['distribution_pct']:>8.2f}%{corr:>11}")
        lines.append(line)
        if r.note:
            notes.append(f"  {r.method}: {r.note}")
    lines.append("distribution: share of 8x8-pixel cells of the left image holding a match; "
                 + ("correct: disparity within 1 px of the ground truth (and rows within 1 px)"
                    if basis == "gt" else
                    "correct: within 1 px of the epipolar line of F fitted to all methods' matches"))
    if notes:
        lines.append("notes:")
        lines.extend(notes)
    return "\n".join(lines)


def write_csv(rows: list[StudyRow], path) -> Path:
    """Write the table as CSV (one row per method; empty cells for "/")."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=COLUMNS)
        wr.writeheader()
        for row in rows:
            vals = row_values(row)
            wr.writerow({k: ("" if vals[k] is None else
                             (f"{vals[k]:.6g}" if isinstance(vals[k], float) else vals[k]))
                         for k in COLUMNS})
    return path


def write_matches(result: MatchResult, folder) -> Path:
    """Write ``<folder>/<method>.csv`` with columns x_left, y_left, x_right, y_right (pixels)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{result.method}.csv"
    data = np.hstack([result.x_left, result.x_right]) if result.num else np.zeros((0, 4))
    np.savetxt(path, data, delimiter=",", fmt="%.6f", header="x_left,y_left,x_right,y_right",
               comments="")
    return path


def read_matches(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a file written by :func:`write_matches`: ``(x_left, x_right)`` (N, 2) each."""
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    if data.shape[1] != 4:
        raise CanopyStereoError(f"{path}: expected 4 columns x_left,y_left,x_right,y_right")
    return data[:, :2], data[:, 2:]


def plot_spread(rows: list[StudyRow], left: np.ndarray, path) -> Path:
    """Save a figure with one panel per method: its matched left points over the left image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from canopy_stereo.io.images import to_gray

    gray = to_gray(np.asarray(left), "left")
    n = len(rows)
    cols = min(4, max(1, n))
    nrows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 3.2 * nrows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, row in zip(axes.ravel(), rows):
        r = row.result
        ax.imshow(gray, cmap="gray", vmin=0, vmax=255)
        if r.num:
            ax.scatter(r.x_left[:, 0], r.x_left[:, 1], s=2, c="lime", linewidths=0)
        ax.set_title(f"{r.method}: {r.num} matches, {100 * r.distribution:.1f}%", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


__all__ = ["DEFAULT_METHODS", "METHODS", "StudyRow", "correspondence_correctness",
           "epipolar_correctness", "format_table",
           "gt_correctness", "parse_methods", "plot_spread", "read_matches", "run_study",
           "write_csv", "write_matches"]
