"""The batch's tidy outputs: ``plants.csv`` (+ ``plants.parquet``) and ``errors.csv``.

``plants.csv``: one row per plant of each bag, columns in this order:

* ``source``: the bag's absolute path (the key ``--resume`` matches on);
* ``plant_index``: the plant of the row (1..N left to right in the image, as the
  measuring pipeline numbers them; 0 = the bag's plants measured as one);
* every key of the bags' ``canopy_stereo`` metadata record (``plant_id``,
  ``plot``, ``treatment``, ``date`` first when present, the others sorted;
  empty where a bag lacks the key; a key equal to a fixed column's name is
  renamed ``meta_<key>``);
* ``recorded_at`` (UTC, ISO 8601, the first measured pair's stamp), ``frames``
  (pairs measured), ``frames_failed``;
* the traits of :data:`~canopy_stereo.batch.work.TRAITS` with their units in
  their names (medians over the frames; empty = not measurable), ``height_reference``
  (the surface the height is measured from: ``pot_rim``, ``soil``, ``ground``, ``none``),
  ``plant_error`` (why the plant could not be measured in a frame it was found in: ``frame K:
  <reason>`` of the first such frame, counted in ``frames_failed``; empty when none; a plant
  measured in no frame has empty traits);
* ``rig`` (``bag``, the ``rig.yaml`` beside the bag or the ``--rig`` file), ``canopy_stereo_version``.

Rows are sorted by ``source`` and ``plant_index``. ``errors.csv``: ``source, reason`` (one line).
Both files are rewritten whole and atomically (temporary file + rename) each
time a bag completes, so an interrupted batch leaves complete tables that hold
every bag finished before the interruption.
"""
from __future__ import annotations

import csv
import math
import os
import tempfile
from pathlib import Path

from canopy_stereo.batch.work import ERROR_COLUMN, REFERENCE_COLUMN, TRAITS

PLANTS_CSV = "plants.csv"
PLANTS_PARQUET = "plants.parquet"
ERRORS_CSV = "errors.csv"

#: Metadata keys placed first, in this order, when present.
PREFERRED_KEYS = ("plant_id", "plot", "treatment", "date")
HEAD = ("source", "plant_index")
TAIL = ("recorded_at", "frames", "frames_failed", *TRAITS, REFERENCE_COLUMN, ERROR_COLUMN, "rig",
        "canopy_stereo_version")
FIXED = frozenset(HEAD + TAIL)
INTEGER_COLUMNS = ("plant_index", "frames", "frames_failed")
NUMERIC_COLUMNS = INTEGER_COLUMNS + tuple(TRAITS)


def format_value(value) -> str:
    """CSV text of a cell: floats with 6 significant digits, NaN/None empty."""
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return str(value)


def metadata_column(key: str) -> str:
    """Column name of metadata key ``key`` (``meta_<key>`` if it clashes with a fixed column)."""
    return f"meta_{key}" if key in FIXED else key


def _key(cells: dict) -> tuple[str, int]:
    """Row key: the source and its plant index (0 when the table has none: older tables)."""
    try:
        index = int(str(cells.get("plant_index") or 0))
    except ValueError:
        index = 0
    return str(cells["source"]), index


def _atomic_write(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def _read_csv(path: Path) -> tuple[list[str], list[dict]]:
    if not path.is_file():
        return [], []
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), [dict(r) for r in reader]


class ResultTable:
    """``OUT/plants.csv`` and ``OUT/errors.csv`` kept on disk as bags complete.

    Args:
        out: output folder (created).
        resume: load the rows already in ``out`` (else start empty; the files are
            replaced at the first write).
        create: create ``out`` now (else at the first write).
    """

    def __init__(self, out, resume: bool = False, create: bool = True):
        self.out = Path(out)
        if create:
            self.out.mkdir(parents=True, exist_ok=True)
        self.rows: dict[tuple[str, int], dict[str, str]] = {}  # (source, plant_index) -> cells
        self.errors: dict[str, str] = {}
        self.metadata_keys: list[str] = []
        if resume:
            cols, rows = _read_csv(self.out / PLANTS_CSV)
            for c in cols:
                if c not in FIXED:
                    self.metadata_keys.append(c)
            for r in rows:
                if r.get("source"):
                    self.rows[_key(r)] = {k: (v or "") for k, v in r.items() if k}
            _, errs = _read_csv(self.out / ERRORS_CSV)
            self.errors = {e["source"]: e.get("reason", "") for e in errs if e.get("source")}

    @property
    def done(self) -> set[str]:
        """Sources with a row in the table."""
        return {source for source, _ in self.rows}

    def columns(self) -> list[str]:
        """Column names in output order."""
        keys = list(dict.fromkeys(self.metadata_keys))
        first = [k for k in PREFERRED_KEYS if k in keys]
        rest = sorted(k for k in keys if k not in PREFERRED_KEYS)
        return [*HEAD, *first, *rest, *TAIL]

    def add_rows(self, rows: list[dict]) -> None:
        """Add (or replace) the rows of a processed bag, one per plant
        (:func:`~canopy_stereo.batch.work.process_bag`), and rewrite the table; the bag's
        earlier rows and error are removed."""
        sources = {str(r["source"]) for r in rows}
        self.rows = {k: v for k, v in self.rows.items() if k[0] not in sources}
        for row in rows:
            cells = {k: format_value(row.get(k)) for k in (*HEAD, *TAIL)}
            for key, value in (row.get("metadata") or {}).items():
                col = metadata_column(key)
                if col not in self.metadata_keys:
                    self.metadata_keys.append(col)
                cells[col] = format_value(value)
            self.rows[_key(cells)] = cells
        for source in sources:
            self.errors.pop(source, None)
        self.write()

    def add_row(self, row: dict) -> None:
        """:meth:`add_rows` of one row."""
        self.add_rows([row])

    def add_error(self, source: str, reason: str) -> None:
        """Record a failed bag (one-line reason) and rewrite ``errors.csv``."""
        self.errors[str(source)] = " ".join(str(reason).split())
        self.write()

    def write(self) -> None:
        """Rewrite ``plants.csv`` and ``errors.csv`` atomically."""
        self.out.mkdir(parents=True, exist_ok=True)
        cols = self.columns()

        def plants(f):
            w = csv.DictWriter(f, fieldnames=cols, restval="", extrasaction="ignore", lineterminator="\n")
            w.writeheader()
            for key in sorted(self.rows):
                w.writerow(self.rows[key])

        def errors(f):
            w = csv.writer(f, lineterminator="\n")
            w.writerow(["source", "reason"])
            for src in sorted(self.errors):
                w.writerow([src, self.errors[src]])

        _atomic_write(self.out / PLANTS_CSV, plants)
        _atomic_write(self.out / ERRORS_CSV, errors)

    def write_parquet(self) -> Path | None:
        """Write ``plants.parquet`` (typed columns) when pyarrow is installed; returns its
        path, or None without pyarrow."""
        try:
            import pyarrow as pa
            import pyarrow.parquet as pq
        except ImportError:
            return None
        cols = self.columns()
        rows = [self.rows[k] for k in sorted(self.rows)]
        arrays = {}
        for c in cols:
            vals = [r.get(c, "") for r in rows]
            if c in INTEGER_COLUMNS:
                arrays[c] = pa.array([int(v) if v else None for v in vals], pa.int64())
            elif c in NUMERIC_COLUMNS:
                arrays[c] = pa.array([float(v) if v else None for v in vals], pa.float64())
            else:
                arrays[c] = pa.array([v if v != "" else None for v in vals], pa.string())
        path = self.out / PLANTS_PARQUET
        tmp = path.with_name(f".{path.name}.tmp")
        pq.write_table(pa.table(arrays), tmp)
        os.replace(tmp, path)
        return path
