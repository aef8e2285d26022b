"""Descriptor matching: nearest neighbour + Lowe's ratio test + mutual (cross) check."""
from __future__ import annotations

import cv2
import numpy as np

#: Above this many descriptor pairs (n_left * n_right) float descriptors go through FLANN.
_BRUTE_FORCE_MAX_PAIRS = 40_000_000


def _knn(query: np.ndarray, train: np.ndarray, k: int, binary: bool):
    """(distances, indices), each (Nq, k), of the k nearest ``train`` rows of each query row.

    Missing neighbours (fewer than k train rows) get distance inf and index -1.
    """
    nq = len(query)
    dist = np.full((nq, k), np.inf)
    idx = np.full((nq, k), -1, dtype=np.int64)
    if nq == 0 or len(train) == 0:
        return dist, idx
    if binary:
        matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    elif nq * len(train) <= _BRUTE_FORCE_MAX_PAIRS:
        matcher = cv2.BFMatcher(cv2.NORM_L2)
    else:
        matcher = cv2.FlannBasedMatcher({"algorithm": 1, "trees": 4}, {"checks": 64})
    knn = matcher.knnMatch(np.ascontiguousarray(query), np.ascontiguousarray(train),
                           k=min(k, len(train)))
    for i, row in enumerate(knn):
        for j, m in enumerate(row[:k]):
            dist[i, j] = m.distance
            idx[i, j] = m.trainIdx
    return dist, idx


def match_descriptors(desc_left: np.ndarray, desc_right: np.ndarray, *, ratio: float = 0.8,
                      mutual: bool = True, binary: bool = False):
    """Putative matches ``(idx_left, idx_right)`` (int64 arrays of equal length).

    A left descriptor i matches its nearest right descriptor j when
    ``d(i, j) < ratio * d(i, second nearest)`` (Lowe's ratio test) and, with
    ``mutual``, when i is also the nearest left descriptor of j.

    Args:
        desc_left, desc_right: (N, D) float32 descriptors, or uint8 for binary ones.
        ratio: ratio-test threshold in (0, 1].
        mutual: require the cross check.
        binary: Hamming distance (ORB, AKAZE) instead of L2.
    """
    if len(desc_left) == 0 or len(desc_right) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    if not binary:
        desc_left = desc_left.astype(np.float32, copy=False)
        desc_right = desc_right.astype(np.float32, copy=False)
    dist, idx = _knn(desc_left, desc_right, 2, binary)
    keep = (idx[:, 0] >= 0) & (dist[:, 0] < ratio * dist[:, 1])
    il = np.nonzero(keep)[0]
    ir = idx[il, 0]
    if mutual and len(il):
        back_d, back_i = _knn(desc_right, desc_left, 1, binary)
        keep = back_i[ir, 0] == il
        il, ir = il[keep], ir[keep]
    return il.astype(np.int64), ir.astype(np.int64)
