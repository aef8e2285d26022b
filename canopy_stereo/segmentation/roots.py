"""Plants that touch in the image told apart by the containers they grow from.

Two potted plants side by side often overlap in the image (the leaves of one
before the other's): their mask is one connected region. Each plant rises from
its own container, though, and seen from the side its lowest parts stand in the
band just above the container (the soil, :func:`~canopy_stereo.segmentation.shape.caps`).
:func:`split_by_roots` seeds one plant per container whose band a mask region
stands in and gives every other pixel of the region to the seed it reaches along
the path with the smallest largest depth step (a marker-controlled watershed on
the depth jumps): a branch reaching sideways belongs to the plant it grows out of,
not to the one it occludes. Regions that stand in at most one band are left whole.
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

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


@njit(cache=True)
def _seeded_forest(order, a, b, seed, n_pixels):
    """Kruskal's minimum spanning forest over the edges ``(a[k], b[k])`` taken in ``order``
    (increasing weight), never joining two trees holding different seeds: each pixel ends in the
    tree of the seed it reaches along the path whose largest step is smallest (0: none)."""
    parent = np.arange(n_pixels)
    label = seed.copy()
    for k in order:
        ra = a[k]
        while parent[ra] != ra:
            parent[ra] = parent[parent[ra]]
            ra = parent[ra]
        rb = b[k]
        while parent[rb] != rb:
            parent[rb] = parent[parent[rb]]
            rb = parent[rb]
        if ra == rb or (label[ra] > 0 and label[rb] > 0 and label[ra] != label[rb]):
            continue
        parent[rb] = ra
        if label[ra] == 0:
            label[ra] = label[rb]
    out = np.empty(n_pixels, np.int64)
    for i in range(n_pixels):
        r = i
        while parent[r] != r:
            r = parent[r]
        out[i] = label[r]
    return out


def split_by_roots(region: np.ndarray, q: np.ndarray, roots: np.ndarray) -> list[np.ndarray] | None:
    """The plants of one mask region (bool (H, W)) that stands in the bands of two or more
    containers (``roots``: :func:`container_bands`), as a list of bool masks (together the
    region), or None when it stands in fewer.

    The region's pixels in a container's band (at least :data:`MIN_ROOT_PIXELS` of them) seed
    that container's plant; every other pixel goes to the seed it reaches through the region
    along the path whose largest relative inverse-depth step ``|dq| / q`` between 8-neighbours
    is smallest (a minimum spanning forest: a plant's leaves are reached through its own
    stems and leaves, not across the depth jump where it occludes the other plant); pixels
    without depth go to the nearest plant.
    """
    touched = np.bincount(roots[region & (roots > 0)])
    kept = np.nonzero(touched >= MIN_ROOT_PIXELS)[0]
    if len(kept) < 2:
        return None
    vs, us = np.nonzero(region)
    y0, y1, x0, x1 = vs.min(), vs.max() + 1, us.min(), us.max() + 1
    reg, qq, rr = region[y0:y1, x0:x1], q[y0:y1, x0:x1], roots[y0:y1, x0:x1]
    ok = reg & np.isfinite(qq) & (qq > 0)
    h, w = reg.shape
    idx = np.arange(h * w).reshape(h, w)
    a, b, wt = [], [], []
    for sa, sb in _pairs((h, w)):
        link = ok[sa] & ok[sb]
        a.append(idx[sa][link])
        b.append(idx[sb][link])
        qa, qb = qq[sa][link], qq[sb][link]
        wt.append(np.abs(qa - qb) / np.maximum(qa, qb))
    ea, eb, ew = np.concatenate(a), np.concatenate(b), np.concatenate(wt)
    seed = np.where(ok & np.isin(rr, kept), rr, 0).astype(np.int64).ravel()
    labels = _seeded_forest(np.argsort(ew, kind="stable"), ea, eb, seed, h * w).reshape(h, w)
    labels[~ok] = 0
    if len(np.unique(labels[labels > 0])) < 2:
        return None
    if (reg & (labels == 0)).any():  # without depth, or cut off from every seed: the nearest plant
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
