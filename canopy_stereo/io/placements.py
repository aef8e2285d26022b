"""Placements files (YAML): where the chessboard stood in each image pair of a world-rig calibration.

The format is described in :mod:`canopy_stereo.geometry.world_rig`, which holds
the :class:`~canopy_stereo.geometry.board_placements.Placements` and checks their
content (:func:`~canopy_stereo.geometry.board_placements.placements_from_dict`); this
module reads and writes the files.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.board_placements import Placements, placements_from_dict
from canopy_stereo.io.yaml_files import read_yaml_file


def load_placements(path) -> Placements:
    """Read and validate a placements YAML file (format: :mod:`canopy_stereo.geometry.world_rig`).

    Returns:
        :class:`Placements` (world unit from the file's ``unit``, default ``mm``).

    Raises:
        CalibrationError: unreadable file, invalid YAML, or any invalid entry
            (the message names the file, the entry and the problem).
    """
    doc = read_yaml_file(path, "placements file", error=CalibrationError)
    return placements_from_dict(doc, source=str(path))


def _fmt(v: float) -> float:
    return float(f"{float(v):.6g}") if abs(v) > 1e-12 else 0.0


def write_placements(placements: Placements, path, *, comment: str | None = None) -> Path:
    """Write ``placements`` as a placements YAML file (readable by :func:`load_placements`).

    Coordinates are written with 6 significant digits. ``comment`` lines go on top.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = []
    if comment:
        lines += [f"# {c}".rstrip() for c in comment.splitlines()]
    cols, rows = placements.pattern
    lines += [f"{f'pattern: {cols}x{rows}':<22}# inner corners, columns x rows",
              f"{f'square: {_fmt(placements.square):g}':<22}# world units",
              f"unit: {placements.unit}",
              f"{'placements:':<22}# one per image pair, in the sorted order of the globs"]
    for p in placements:
        vec = lambda v: "[" + ", ".join(f"{_fmt(x):.6g}" for x in v) + "]"  # noqa: E731
        lines.append(f"  - pair: {p.pair}")
        lines.append(f"    origin: {vec(p.origin)}")
        lines.append(f"    x_axis: {vec(p.x_axis)}")
        lines.append(f"    y_axis: {vec(p.y_axis)}")
        if p.label:
            lines.append(f"    label: {yaml.safe_dump(p.label, width=1 << 30).splitlines()[0]}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
