"""Metadata a lab already has: in its file names and in a sidecar table (as PlantCV's workflows).

* :func:`fields_from_name`: ``--name-pattern "{plant_id}_{treatment}_{date}"`` reads the
  fields of a bag's file name (without ``.mcap``): each ``{key}`` matches one or more
  characters, the text between them literally (a regular expression with named groups
  ``(?P<key>...)`` works too). A name that does not match is an error naming both.
* :func:`read_sidecar` / :func:`sidecar_row`: ``--metadata TABLE.csv``, one row per bag
  keyed by its file name (column ``file``, ``filename`` or ``bag``, else the first column;
  with or without ``.mcap``), the other columns its metadata.
"""
from __future__ import annotations

import csv
import re
from pathlib import Path

from canopy_stereo.errors import CanopyStereoError

#: Names of the key column of a sidecar table, first found wins (else the first column).
KEY_COLUMNS = ("file", "filename", "file_name", "bag")
_FIELD = re.compile(r"\{([A-Za-z_][A-Za-z0-9_]*)\}")


def pattern_regex(pattern: str) -> re.Pattern:
    """The compiled regular expression of a name pattern (see the module docstring)."""
    if "(?P<" in pattern:
        try:
            return re.compile(pattern)
        except re.error as exc:
            raise CanopyStereoError(f"--name-pattern {pattern!r} is not a valid regular expression: {exc}") from None
    fields = _FIELD.findall(pattern)
    if not fields:
        raise CanopyStereoError(f"--name-pattern {pattern!r} names no field: write them as {{key}}, "
                                "e.g. '{plant_id}_{date}'")
    if len(set(fields)) != len(fields):
        raise CanopyStereoError(f"--name-pattern {pattern!r} names a field twice")
    parts, last = [], 0
    for m in _FIELD.finditer(pattern):
        parts.append(re.escape(pattern[last:m.start()]))
        parts.append(f"(?P<{m.group(1)}>.+?)")
        last = m.end()
    parts.append(re.escape(pattern[last:]))
    return re.compile("".join(parts))


def fields_from_name(name: str, pattern: str) -> dict[str, str]:
    """``{key: value}`` of a file name (``.mcap`` dropped) read with ``pattern``;
    :class:`CanopyStereoError` when it does not match."""
    stem = name[:-5] if name.endswith(".mcap") else name
    m = pattern_regex(pattern).fullmatch(stem)
    if m is None:
        raise CanopyStereoError(f"file name {stem!r} does not match --name-pattern {pattern!r}")
    return {k: v for k, v in m.groupdict().items() if v is not None}


def read_sidecar(path) -> dict[str, dict[str, str]]:
    """file name (without ``.mcap``) -> {key: value} of a sidecar CSV (see the module
    docstring); :class:`CanopyStereoError` for a missing or malformed table."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise CanopyStereoError(f"cannot read the metadata table {path}: {exc}") from None
    rows = [r for r in rows if any(c.strip() for c in r)]
    if len(rows) < 2:
        raise CanopyStereoError(f"metadata table {path} has no rows (a header line, then one line per bag)")
    header = [h.strip() for h in rows[0]]
    lowered = [h.lower() for h in header]
    key = next((lowered.index(k) for k in KEY_COLUMNS if k in lowered), 0)
    if len(set(header)) != len(header) or not all(header):
        raise CanopyStereoError(f"metadata table {path}: column names must be present and distinct, got {header}")
    table: dict[str, dict[str, str]] = {}
    for n, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise CanopyStereoError(f"metadata table {path} line {n}: {len(row)} cells, the header has {len(header)}")
        name = Path(row[key].strip()).name
        name = name[:-5] if name.endswith(".mcap") else name
        if name in table:
            raise CanopyStereoError(f"metadata table {path} line {n}: file {name!r} is listed twice")
        table[name] = {h: c.strip() for i, (h, c) in enumerate(zip(header, row)) if i != key}
    return table


def sidecar_row(table: dict, bag_path) -> dict[str, str]:
    """The sidecar metadata of the bag at ``bag_path`` ({} when the table has no row for it)."""
    name = Path(bag_path).name
    return dict(table.get(name[:-5] if name.endswith(".mcap") else name, {}))
