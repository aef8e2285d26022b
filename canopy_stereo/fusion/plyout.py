"""Write a fused model as PLY with its per-point view and point counts.

Same conventions as :func:`canopy_stereo.io.ply.write_ply` (binary little
endian, float32 ``x y z``, uchar ``red green blue``, ``comment unit <unit>``)
plus two vertex properties: ``uchar views`` (views that saw the point) and
``uint points`` (input points merged into it). :func:`canopy_stereo.io.ply.read_ply`
returns them in ``PointCloud.extra``; MeshLab and CloudCompare show them as
scalar fields.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def write_fused_ply(path, fused, comments=()) -> Path:
    """Write a :class:`~canopy_stereo.fusion.fuse.FusedCloud` to ``path``; returns the path."""
    path = Path(path)
    n = len(fused.points)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if fused.colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    fields += [("views", "u1"), ("points", "<u4")]
    rec = np.empty(n, dtype=fields)
    pts = np.asarray(fused.points, np.float32)
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if fused.colors is not None:
        rec["red"], rec["green"], rec["blue"] = fused.colors[:, 0], fused.colors[:, 1], fused.colors[:, 2]
    rec["views"] = np.clip(fused.view_count, 0, 255)
    rec["points"] = np.clip(fused.point_count, 0, 2 ** 32 - 1)
    lines = ["ply", "format binary_little_endian 1.0", f"comment unit {fused.unit}",
             "comment generator canopy_stereo fusion", f"comment voxel {fused.voxel:g} {fused.unit}"]
    lines += [f"comment {c}" for c in comments]
    lines += [f"element vertex {n}", "property float x", "property float y", "property float z"]
    if fused.colors is not None:
        lines += ["property uchar red", "property uchar green", "property uchar blue"]
    lines += ["property uchar views", "property uint points", "end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(lines) + "\n").encode("ascii"))
        f.write(rec.tobytes())
    return path
