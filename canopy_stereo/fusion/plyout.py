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

from canopy_stereo.io.ply import write_ply


def write_fused_ply(path, fused, *, comments=()) -> Path:
    """Write a :class:`~canopy_stereo.fusion.fuse.FusedCloud` to ``path``; returns the path."""
    props = {"views": np.clip(fused.view_count, 0, 255).astype(np.uint8),
             "points": np.clip(fused.point_count, 0, 2 ** 32 - 1).astype(np.uint32)}
    return write_ply(path, fused.points, colors=fused.colors, unit=fused.unit, properties=props,
                     comments=["generator canopy_stereo fusion", f"voxel {fused.voxel:g} {fused.unit}",
                               *comments])
