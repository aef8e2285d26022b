"""Voxel grids over point clouds: keys, down-sampling and neighbourhoods.

Voxel ``(i, j, k)`` covers ``[i, i+1) * size`` along x (and likewise y, z),
world units. Each voxel index triple is packed into one int64 key (21 bits
per axis, offset so negative indices work), so grouping points by voxel is a
sort of integers.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import CanopyStereoError

_BITS = 21
_OFFSET = 1 << (_BITS - 1)
_LIMIT = _OFFSET - 2  # keep room for the +-1 neighbour offsets

#: The 27 offsets of a voxel's 3x3x3 neighbourhood (itself included).
NEIGHBOURHOOD_27 = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)],
                            dtype=np.int64)


def voxel_indices(points, size: float) -> np.ndarray:
    """(N, 3) int64 voxel indices ``floor(p / size)`` of points (N, 3) (finite)."""
    if not size > 0:
        raise CanopyStereoError(f"voxel size must be positive, got {size}")
    ijk = np.floor(np.asarray(points, np.float64) / float(size))
    if len(ijk) and np.abs(ijk).max() > _LIMIT:
        raise CanopyStereoError(f"the cloud spans more than {_LIMIT} voxels of {size} from the origin; "
                                "use a larger voxel or check the unit")
    return ijk.astype(np.int64)


def pack_keys(ijk) -> np.ndarray:
    """(N,) int64 keys of voxel indices (N, 3)."""
    ijk = np.asarray(ijk, np.int64) + _OFFSET
    return (ijk[:, 0] << (2 * _BITS)) | (ijk[:, 1] << _BITS) | ijk[:, 2]


def unpack_keys(keys) -> np.ndarray:
    """Inverse of :func:`pack_keys`: (N, 3) int64 voxel indices."""
    keys = np.asarray(keys, np.int64)
    mask = (1 << _BITS) - 1
    return np.stack([(keys >> (2 * _BITS)) & mask, (keys >> _BITS) & mask, keys & mask], axis=1) - _OFFSET


def voxel_keys(points, size: float) -> np.ndarray:
    """(N,) int64 voxel keys of points (N, 3)."""
    return pack_keys(voxel_indices(points, size))


def group_by_key(keys):
    """``(unique_keys, inverse)``: sorted distinct keys and each point's group index."""
    return np.unique(np.asarray(keys, np.int64), return_inverse=True)


def voxel_downsample(points, size: float, *, colors=None):
    """Average the points (and colours) falling in each voxel.

    Args:
        points: (N, 3) finite points, world units.
        size: voxel edge, world units.
        colors: optional (N, 3) uint8 RGB.

    Returns:
        ``(centroids (M, 3) float64, colours (M, 3) uint8 or None, counts (M,) int64)``
        with one row per occupied voxel.
    """
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros((0, 3)), (None if colors is None else np.zeros((0, 3), np.uint8)), np.zeros(0, np.int64)
    _, inv = group_by_key(voxel_keys(pts, size))
    counts = np.bincount(inv)
    means = np.stack([np.bincount(inv, weights=pts[:, a]) for a in range(3)], axis=1) / counts[:, None]
    cols = None
    if colors is not None:
        c = np.asarray(colors, np.float64).reshape(-1, 3)
        cols = np.stack([np.bincount(inv, weights=c[:, a]) for a in range(3)], axis=1) / counts[:, None]
        cols = np.clip(np.rint(cols), 0, 255).astype(np.uint8)
    return means, cols, counts


def dilate_keys(keys) -> np.ndarray:
    """Sorted distinct keys of all voxels within the 3x3x3 neighbourhood of ``keys``."""
    ijk = unpack_keys(np.unique(np.asarray(keys, np.int64)))
    around = (ijk[:, None, :] + NEIGHBOURHOOD_27[None]).reshape(-1, 3)
    return np.unique(pack_keys(around))
