"""Per-plant plots of each trait over the recording dates (``OUT/plots/<plant>.png``).

A plant is the ``plant_id`` metadata value (each bag is its own plant when
there is no ``plant_id``). Its bags are placed along the x axis by the
``date`` metadata value when every bag of the plant has one that parses as an
ISO date, otherwise by ``recorded_at`` (the first frame's stamp). One panel per
trait that has a value; points are bag medians, labelled with their frame counts.
"""
from __future__ import annotations

import datetime as _dt
import math
import re
from pathlib import Path

from canopy_stereo.batch.work import TRAITS


def _when(row: dict, use_date: bool):
    text = row.get("date", "") if use_date else row.get("recorded_at", "")
    try:
        if use_date:
            return _dt.datetime.fromisoformat(text)
        return _dt.datetime.strptime(text, "%Y-%m-%dT%H:%M:%SZ")
    except ValueError:
        return None


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("._") or "plant"


def plot_traits(table, folder) -> list[Path]:
    """Draw one PNG per plant of a :class:`~canopy_stereo.batch.table.ResultTable`;
    returns the files written ([] without matplotlib)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.dates as mdates
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    plants: dict[str, list[dict]] = {}
    for src in sorted(table.rows):
        row = table.rows[src]
        plant = row.get("plant_id") or Path(src).stem
        plants.setdefault(plant, []).append(row)
    written = []
    for plant, rows in sorted(plants.items()):
        use_date = all(_when(r, True) is not None for r in rows)
        pts = [(_when(r, use_date), r) for r in rows]
        pts = sorted([p for p in pts if p[0] is not None], key=lambda p: p[0])
        if not pts:
            continue
        traits = [t for t in TRAITS if any(r.get(t) for _, r in pts)]
        if not traits:
            continue
        ncol = 3
        nrow = math.ceil(len(traits) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 2.8 * nrow), squeeze=False)
        for ax, trait in zip(axes.flat, traits):
            xs = [w for w, r in pts if r.get(trait)]
            ys = [float(r[trait]) for _, r in pts if r.get(trait)]
            ns = [r.get("frames", "") for _, r in pts if r.get(trait)]
            ax.plot(xs, ys, "o-", color="tab:green")
            for x, y, n in zip(xs, ys, ns):
                ax.annotate(f"n={n}", (x, y), textcoords="offset points", xytext=(0, 5),
                            ha="center", fontsize=7, color="0.4")
            ax.set_title(trait, fontsize=9)
            ax.xaxis.set_major_locator(mdates.AutoDateLocator(minticks=2, maxticks=5))
            ax.xaxis.set_major_formatter(mdates.DateFormatter("%Y-%m-%d"))
            ax.tick_params(axis="x", labelrotation=30, labelsize=7)
            ax.tick_params(axis="y", labelsize=7)
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(traits):]:
            ax.set_visible(False)
        fig.suptitle(f"plant {plant}: traits over {'dates' if use_date else 'recording times'} "
                     "(bag medians; n = frames)", fontsize=10)
        fig.tight_layout()
        path = folder / f"{_safe_name(plant)}.png"
        fig.savefig(path, dpi=90)
        plt.close(fig)
        written.append(path)
    return written
