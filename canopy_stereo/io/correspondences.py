"""2D-3D correspondence files (CSV) for the Gold Standard calibration
(:func:`~canopy_stereo.geometry.calibration.calibrate_stereo_points`)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CalibrationError


def read_correspondences_csv(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read a CSV with columns ``X,Y,Z,u_left,v_left,u_right,v_right`` (header required).

    Returns ``(X (N,3), x_left (N,2), x_right (N,2))``.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{path} is not a text CSV (byte {exc.start} is not UTF-8); "
                               "expected columns X,Y,Z,u_left,v_left,u_right,v_right") from None
    try:
        rows = [r for r in csv.reader(text.splitlines()) if r and not r[0].lstrip().startswith("#")]
    except csv.Error as exc:
        raise CalibrationError(f"{path} is not a readable CSV: {exc}") from None
    if not rows:
        raise CalibrationError(f"{path} is empty")
    header = [h.strip() for h in rows[0]]
    need = ["X", "Y", "Z", "u_left", "v_left", "u_right", "v_right"]
    missing = [c for c in need if c not in header]
    if missing:
        raise CalibrationError(f"{path}: missing column(s) {', '.join(missing)} (need {','.join(need)})")
    idx = [header.index(c) for c in need]
    data = []
    for lineno, r in enumerate(rows[1:], start=2):
        try:
            values = [float(r[i]) for i in idx]
        except (ValueError, IndexError):
            raise CalibrationError(f"{path}: line {lineno} is not 7 numbers") from None
        if not all(np.isfinite(values)):
            raise CalibrationError(f"{path}: line {lineno} has a non-finite value (nan or inf)")
        data.append(values)
    table = np.array(data, dtype=np.float64).reshape(-1, 7)
    return table[:, :3], table[:, 3:5], table[:, 5:7]
