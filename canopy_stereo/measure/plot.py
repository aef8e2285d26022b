"""Top and side views of a measured canopy with its dimensions drawn (PNG).

Matplotlib (Agg backend) is imported only when a plot is made.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.measure.units import lab_report, mm_per_unit

#: Most points drawn per view.
MAX_PLOT_POINTS = 30000


def _dimension(ax, p0, p1, text, offset, color="k"):
    """A double-headed dimension arrow from p0 to p1 with its label, shifted by ``offset``."""
    p0 = np.asarray(p0, float) + offset
    p1 = np.asarray(p1, float) + offset
    ax.annotate("", xy=p1, xytext=p0, arrowprops=dict(arrowstyle="<->", color=color, lw=1.2))
    mid = 0.5 * (p0 + p1)
    vertical = abs(p1[1] - p0[1]) > abs(p1[0] - p0[0])
    ax.text(mid[0], mid[1], text, color=color, fontsize=9, ha="center", va="center",
            rotation=90 if vertical else 0,
            bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="none", alpha=0.8))


def plot_views(measurement, path, *, title: str | None = None, dpi: int = 120) -> Path:
    """Write a PNG with the top view (x-y) and side view (x-z) of the canopy.

    Args:
        measurement: a :class:`~canopy_stereo.measure.scene.SceneMeasurement`.
        path: output PNG path.
        title: optional figure title.

    The views are in the measuring frame (x across, y away from the camera,
    z up), in millimetres (areas cm^2, volumes cm^3: the package's one unit set) with the
    canopy's bounding box, its width, depth and height, and
    each reliable leaf's length and width lines labelled with its id.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as exc:  # pragma: no cover - matplotlib is a declared extra
        raise CanopyStereoError(f"plotting needs matplotlib ({exc}); pip install matplotlib") from None
    report = measurement.report
    mm = mm_per_unit(report.get("unit", "mm"))  # the views in millimetres, whatever the cloud's unit
    lab = lab_report(report)  # labels in the one unit set: mm, cm^2, cm^3
    unit = "mm"
    frame = measurement.frame
    F = frame.to_frame(measurement.canopy_points) * mm
    if len(F) > MAX_PLOT_POINTS:
        F = F[np.random.default_rng(0).choice(len(F), MAX_PLOT_POINTS, replace=False)]
    can = lab["canopy"]
    lo, hi = np.asarray(can["bbox_min"]), np.asarray(can["bbox_max"])
    span = float(np.max(hi - lo)) or 1.0
    fig, axes = plt.subplots(1, 2, figsize=(12, 6))
    views = (("Top view (looking down)", 0, 1, "x across", "y away from camera",
              (("width", 0), ("depth", 1))),
             ("Side view (from the camera)", 0, 2, "x across", "z up",
              (("width", 0), ("height", 2))))
    for ax, (name, i, j, xl, yl, dims) in zip(axes, views):
        other = 3 - i - j
        ax.scatter(F[:, i], F[:, j], c=F[:, other], s=1.0, cmap="viridis", linewidths=0, rasterized=True)
        ax.plot([lo[i], hi[i], hi[i], lo[i], lo[i]], [lo[j], lo[j], hi[j], hi[j], lo[j]],
                color="0.4", lw=0.8, ls="--")
        for dim, k in dims:
            value = can[dim]
            if k == i:
                _dimension(ax, (lo[i], lo[j]), (hi[i], lo[j]), f"{dim} {value:.1f} {unit}",
                           np.array([0.0, -0.06 * span]))
            else:
                _dimension(ax, (lo[i], lo[j]), (lo[i], hi[j]), f"{dim} {value:.1f} {unit}",
                           np.array([-0.06 * span, 0.0]))
        if j == 2 and frame.ground_plane is not None:
            ax.axhline(0.0, color="saddlebrown", lw=1.0)
            ax.text(lo[i], 0.0, "ground", color="saddlebrown", fontsize=8, va="bottom")
        for leaf, raw in zip(lab.get("leaves", []), report.get("leaves", [])):
            if not leaf.get("reliable", True):
                continue  # edge-on or cut-off leaves: their lines would mislead
            ends = frame.to_frame(np.asarray(raw["ends"])) * mm
            wends = frame.to_frame(np.asarray(raw["width_ends"])) * mm
            ax.plot(ends[:, i], ends[:, j], color="crimson", lw=1.2)
            ax.plot(wends[:, i], wends[:, j], color="darkorange", lw=1.0)
            c = ends.mean(axis=0)
            ax.text(c[i], c[j], f"{leaf['id']}: {leaf['length']:.0f}x{leaf['width']:.0f}",
                    fontsize=7, color="crimson", ha="left", va="bottom")
        ax.set_title(name)
        ax.set_xlabel(f"{xl} ({unit})")
        ax.set_ylabel(f"{yl} ({unit})")
        ax.set_aspect("equal", adjustable="datalim")
        ax.margins(0.12)
        ax.grid(True, lw=0.3, alpha=0.5)
    sub = (f"hull volume {can['hull_volume']:.4g} cm^3, voxel volume {can['voxel_volume']:.4g} "
           f"cm^3 ({can['voxel_size']:g} mm voxels)")
    if can.get("leaf_area") is not None:
        sub += f", leaf area {can['leaf_area']:.4g} cm^2"
    fig.suptitle((title + "\n" if title else "") + sub + "\nleaves: length (red) x width (orange)",
                 fontsize=10)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
