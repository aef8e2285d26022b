"""Shortest paths over the surface of an organized grid (Dijkstra, compiled).

Nodes are the pixels of a mask; a pixel is joined to the pixels at the
offsets ``(du, dv)`` with ``max(|du|, |dv|) <= 2`` and ``gcd(du, dv) = 1``
(16 directions, at most 2.8 % longer than the straight path on a flat grid),
weighted by the 3D distance between the two surface points. Used to find the
two ends of a leaf (the geodesic diameter), not to measure its length.
"""
from __future__ import annotations

import heapq
from math import gcd

import numpy as np
from numba import njit


def _offsets(radius: int = 2) -> np.ndarray:
    offs = [(dv, du) for dv in range(-radius, radius + 1) for du in range(-radius, radius + 1)
            if (du or dv) and gcd(abs(du), abs(dv)) == 1]
    return np.array(offs, dtype=np.int64)


OFFSETS = _offsets(2)


@njit(cache=True)
def _dijkstra(points, inside, start_v, start_u, offsets):  # pragma: no cover - compiled
    h, w = inside.shape
    dist = np.full((h, w), np.inf)
    dist[start_v, start_u] = 0.0
    heap = [(0.0, start_v * w + start_u)]
    while heap:
        d, idx = heapq.heappop(heap)
        v = idx // w
        u = idx - v * w
        if d > dist[v, u]:
            continue
        for k in range(offsets.shape[0]):
            dv = offsets[k, 0]
            du = offsets[k, 1]
            v2 = v + dv
            u2 = u + du
            if v2 < 0 or v2 >= h or u2 < 0 or u2 >= w or not inside[v2, u2]:
                continue
            # a knight's move must not jump over the outside: one of the two
            # pixels it passes between must be inside the mask
            if abs(dv) == 2:
                if not (inside[v + dv // 2, u] or inside[v + dv // 2, u + du]):
                    continue
            elif abs(du) == 2:
                if not (inside[v, u + du // 2] or inside[v + dv, u + du // 2]):
                    continue
            dx = points[v2, u2, 0] - points[v, u, 0]
            dy = points[v2, u2, 1] - points[v, u, 1]
            dz = points[v2, u2, 2] - points[v, u, 2]
            nd = d + np.sqrt(dx * dx + dy * dy + dz * dz)
            if nd < dist[v2, u2]:
                dist[v2, u2] = nd
                heapq.heappush(heap, (nd, v2 * w + u2))
    return dist


def geodesic_distances(points: np.ndarray, inside: np.ndarray, start: tuple[int, int]) -> np.ndarray:
    """(h, w) shortest surface distance (world units) from pixel ``start = (v, u)``.

    ``points`` (h, w, 3) must be finite on ``inside`` (h, w) bool; pixels not
    reachable inside the mask get ``inf``.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    ins = np.ascontiguousarray(inside, dtype=np.bool_)
    return _dijkstra(pts, ins, int(start[0]), int(start[1]), OFFSETS)


def geodesic_diameter(points: np.ndarray, inside: np.ndarray, *, sweeps: int = 3):
    """Approximate ends of the longest shortest path over a mask (double sweep).

    Starts at the pixel nearest the centroid of the mask, walks to the farthest
    pixel and from there again (``sweeps`` times in all), keeping the best pair.

    Returns:
        ``((v_a, u_a), (v_b, u_b), distance)`` with the distance in world units.
    """
    vs, us = np.nonzero(inside)
    c = np.argmin((vs - vs.mean()) ** 2 + (us - us.mean()) ** 2)
    a = (int(vs[c]), int(us[c]))
    best = (a, a, 0.0)
    for _ in range(max(2, sweeps)):
        dist = geodesic_distances(points, inside, a)
        d = np.where(np.isfinite(dist), dist, -1.0)
        fv, fu = np.unravel_index(int(np.argmax(d)), d.shape)
        far = (int(fv), int(fu))
        if d[far] > best[2]:
            best = (a, far, float(d[far]))
        a = far
    return best
