"""Plants that touch in the image told apart by the containers they grow from.

Two potted plants side by side often overlap in the image (the leaves of one
before the other's): their mask is one connected region. Each plant rises from
its own container, though, and seen from the side its lowest parts stand in the
band just above the container (the soil, :func:`~canopy_stereo.segmentation.shape.caps`).
:func:`split_by_roots` cuts a mask region that stands in the bands of two or more
containers along its depth jumps into *parts* (pixels linked to an 8-neighbour
whose inverse depth is within :data:`PART_JUMP` of theirs), roots each part that
stands in a container's band in that container, and gives every other part to the
rooted group it shares the longest border with (a branch reaching sideways belongs
to the plant it grows out of, not to the one behind it). Regions that stand in at
most one band are left whole.
"""
from __future__ import annotations

import cv2
import numpy as np

#: Largest relative inverse-depth step (|dq| / q, i.e. |dz| / z) between 8-neighbours of one part.
PART_JUMP = 0.006
#: Fewest pixels of a part in a container's band that root it there.
MIN_ROOT_PIXELS = 20

#: 8-neighbour offsets (half of them: each pair once).
_STEPS = ((0, 1), (1, 0), (1, 1), (1, -1))


def container_bands(solids: np.ndarray, bands: np.ndarray) -> np.ndarray:
    """(H, W) int32: the number (1..) of the solid object (8-connected region of ``solids``)
    whose band above it (``bands``, bool) each pixel lies in; 0 elsewhere. A pixel in the
    bands of two objects takes the nearer object (by column overlap: the first one found)."""
    n, lab = cv2.connectedComponents(np.asarray(solids, np.uint8), connectivity=8)
    out = np.zeros(lab.shape, np.int32)
    if n <= 1:
        return out
    band = np.asarray(bands, bool)
    # a band pixel belongs to the solid straight below it: the first solid label down its column
    below = np.zeros(lab.shape, np.int32)
    nxt = np.zeros(lab.shape[1], np.int32)
    for v in range(lab.shape[0] - 1, -1, -1):
        nxt = np.where(lab[v] > 0, lab[v], nxt)
        below[v] = nxt
    out[band] = below[band]
    return out


def _pairs(shape):
    """For each half-neighbourhood step, the slices of the two pixels of each pair."""
    h, w = shape
    for dy, dx in _STEPS:
        a = (slice(0, h - dy), slice(max(0, -dx), w + min(0, -dx)))
        b = (slice(dy, h), slice(max(0, dx), w + min(0, dx)))
        yield a, b


def depth_parts(region: np.ndarray, q: np.ndarray, *, jump: float = PART_JUMP) -> np.ndarray:
    """(H, W) int32 labels 1.. of the parts of ``region`` (bool) whose pixels are linked to an
    8-neighbour of the region with an inverse depth ``q`` within ``jump`` (relative) of theirs;
    pixels without ``q`` are 0."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    h, w = region.shape
    ok = region & np.isfinite(q)
    idx = np.arange(h * w).reshape(h, w)
    rows, cols = [], []
    for a, b in _pairs((h, w)):
        with np.errstate(invalid="ignore"):
            link = ok[a] & ok[b] & (np.abs(q[a] - q[b]) <= jump * np.maximum(q[a], q[b]))
        rows.append(idx[a][link])
        cols.append(idx[b][link])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), np.int8), (r, c)), shape=(h * w, h * w))
    _, comp = connected_components(graph, directed=False)
    comp = comp.reshape(h, w)
    out = np.zeros((h, w), np.int32)
    _, out[ok] = np.unique(comp[ok], return_inverse=True)
    out[ok] += 1
    return out


def split_by_roots(region: np.ndarray, q: np.ndarray, roots: np.ndarray, *,
                   jump: float = PART_JUMP) -> list[np.ndarray] | None:
    """The plants of one mask region (bool (H, W)) that stands in the bands of two or more
    containers (``roots``: :func:`container_bands`), as a list of bool masks (together the
    region), or None when it stands in fewer (or no part can be rooted apart).

    Parts (:func:`depth_parts`) with at least :data:`MIN_ROOT_PIXELS` pixels in a band are
    rooted in the container they stand in most; the other parts join, largest shared border
    first, the rooted group they touch; pixels without depth go to the nearest group.
    """
    touched = np.bincount(roots[region & (roots > 0)])
    if np.count_nonzero(touched >= MIN_ROOT_PIXELS) < 2:
        return None
    vs, us = np.nonzero(region)
    y0, y1, x0, x1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
    reg, qq, rr = region[y0:y1, x0:x1], q[y0:y1, x0:x1], roots[y0:y1, x0:x1]
    parts = depth_parts(reg, qq, jump=jump)
    n = int(parts.max()) + 1
    # pixels of each part in each container's band
    nroot = int(rr.max()) + 1
    sel = (parts > 0) & (rr > 0)
    hits = np.bincount(parts[sel] * nroot + rr[sel], minlength=n * nroot).reshape(n, nroot)
    group = np.where(hits.max(axis=1) >= MIN_ROOT_PIXELS, hits.argmax(axis=1), 0)
    group[0] = 0
    if len(np.unique(group[group > 0])) < 2:
        return None
    # shared border (8-neighbour pixel pairs) between parts
    border = np.zeros((n, n), np.int64)
    for a, b in _pairs(parts.shape):
        pa, pb = parts[a], parts[b]
        cross = (pa > 0) & (pb > 0) & (pa != pb)
        np.add.at(border, (pa[cross], pb[cross]), 1)
    border += border.T
    while True:
        free = group == 0
        free[0] = False
        if not free.any():
            break
        rooted = group > 0
        touch = border[np.ix_(free, rooted)]
        if touch.max(initial=0) == 0:
            break
        fi, ri = np.unravel_index(np.argmax(touch), touch.shape)
        group[np.nonzero(free)[0][fi]] = group[np.nonzero(rooted)[0][ri]]
    labels = group[parts]
    # pixels without depth (or parts cut off from every rooted one): the nearest group
    if (reg & (labels == 0)).any():
        _, (iy, ix) = _nearest_labelled(labels > 0)
        labels = np.where(reg & (labels == 0), labels[iy, ix], labels)
    out = []
    for g in np.unique(labels[reg & (labels > 0)]):
        m = np.zeros(region.shape, bool)
        m[y0:y1, x0:x1] = reg & (labels == g)
        out.append(m)
    return out


def _nearest_labelled(labelled: np.ndarray):
    """Distance to and indices of the nearest ``labelled`` pixel of every pixel."""
    from scipy import ndimage

    return ndimage.distance_transform_edt(~labelled, return_indices=True)
