"""ELAS stages 3-4: Delaunay triangulation of the support points and the plane prior.

The left image is triangulated on ``(u, v)``, the right one on ``(u - d, v)``
(support points lie on a regular grid, so many quadruples are co-circular: any
valid Delaunay diagonal is accepted).
Each triangle carries the disparity plane ``d = a*u + b*v + c`` through its
vertices in its *own* image coordinates and in the *other* image's; the plane is
valid (it contributes the prior) when ``|a| < 0.7`` in both.

Triangles are rasterised into an int32 map of triangle indices (-1 outside the
hull): a pixel centre on a shared edge belongs to the later triangle.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from canopy_stereo.elas.sweephull import delaunay_kernel, delaunay_triangles
from canopy_stereo.errors import CanopyStereoError

#: A plane is used as a prior only if its u-slope is below this in both images.
MAX_PLANE_SLOPE = 0.7


def triangulate(uv: np.ndarray) -> np.ndarray:
    """Delaunay triangles of points ``uv`` (N, 2) as int32 (T, 3) vertex indices
    (:func:`~canopy_stereo.elas.sweephull.delaunay_triangles`).

    Fewer than 3 distinct points, or all of them on a line, give no triangles (0, 3);
    a repeated point is used once.
    """
    return delaunay_triangles(uv)


@njit(cache=True, nogil=True)
def _fit_planes(u, v, d, triangles):
    out = np.zeros((triangles.shape[0], 3), dtype=np.float32)
    for t in range(triangles.shape[0]):
        i, j, k = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        # Cramer's rule on [[u, v, 1]] (a, b, c)^T = d, in float64
        u0, v0, d0 = float(u[i]), float(v[i]), float(d[i])
        u1, v1, d1 = float(u[j]), float(v[j]), float(d[j])
        u2, v2, d2 = float(u[k]), float(v[k]), float(d[k])
        det = u0 * (v1 - v2) - v0 * (u1 - u2) + (u1 * v2 - u2 * v1)
        if abs(det) < 1e-9:
            continue
        a = (d0 * (v1 - v2) - v0 * (d1 - d2) + (d1 * v2 - d2 * v1)) / det
        b = (u0 * (d1 - d2) - d0 * (u1 - u2) + (u1 * d2 - u2 * d1)) / det
        c = (u0 * (v1 * d2 - v2 * d1) - v0 * (u1 * d2 - u2 * d1) + d0 * (u1 * v2 - u2 * v1)) / det
        out[t, 0] = a
        out[t, 1] = b
        out[t, 2] = c
    return out


def fit_planes(u: np.ndarray, v: np.ndarray, d: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Planes ``d = a*u + b*v + c`` through each triangle's vertices.

    Args:
        u, v, d: vertex coordinates (N,) in pixels.
        triangles: int (T, 3) vertex indices.

    Returns:
        float32 (T, 3) rows ``(a, b, c)``, solved in float64; a singular system
        (collinear vertices) gives the zero plane.
    """
    return _fit_planes(np.ascontiguousarray(u, np.float64), np.ascontiguousarray(v, np.float64),
                       np.ascontiguousarray(d, np.float64),
                       np.ascontiguousarray(np.asarray(triangles, np.int64).reshape(-1, 3)))


def triangle_planes(points: np.ndarray, right_image: bool):
    """Triangulate the support points for one image and fit its planes.

    The triangulation (:func:`~canopy_stereo.elas.sweephull.delaunay_kernel`) and the
    plane fits run without the GIL; the numpy glue between them is a few (N,) arrays.

    Args:
        points: int (N, 3) support points ``(u, v, d)`` in left-image pixels.
        right_image: triangulate on ``(u - d, v)`` instead of ``(u, v)``.

    Returns:
        ``(vertices, triangles, planes, valid)``: vertices float64 (N, 2) in the
        image's own pixels, triangles int32 (T, 3), planes float32 (T, 3) in own
        coordinates, valid bool (T,).
    """
    points = np.asarray(points, dtype=np.int64).reshape(-1, 3)
    u_left, v, d = points[:, 0], points[:, 1], points[:, 2]
    u_right = u_left - d
    u_own, u_other = (u_right, u_left) if right_image else (u_left, u_right)
    vertices = np.column_stack([u_own, v]).astype(np.float64)
    triangles = delaunay_kernel(np.ascontiguousarray(vertices[:, 0]),
                                np.ascontiguousarray(vertices[:, 1]))
    planes = fit_planes(u_own, v, d, triangles)
    other = fit_planes(u_other, v, d, triangles)
    valid = (np.abs(planes[:, 0]) < MAX_PLANE_SLOPE) & (np.abs(other[:, 0]) < MAX_PLANE_SLOPE)
    return vertices, triangles, planes, valid


@njit(cache=True, inline="always")
def _edge_span(x0, y0, x1, y1, vmin, vmax, lo, hi, eps, row_step):
    """Widen the row spans ``lo[v - vmin]``, ``hi[v - vmin]`` by edge (x0, y0) -> (x1, y1)
    on every row ``v`` in ``[vmin, vmax]``, a multiple of ``row_step``, whose centre line
    meets it (within ``eps``)."""
    if y0 == y1:
        # a horizontal edge counts on the rows within eps of it, with both end points
        for v in range(max(vmin, int(np.floor(y0)) - 1), min(vmax, int(np.ceil(y0)) + 1) + 1):
            if abs(float(v) - y0) <= eps and v % row_step == 0:
                lo[v - vmin] = min(lo[v - vmin], x0, x1)
                hi[v - vmin] = max(hi[v - vmin], x0, x1)
        return
    # rows v with min(y0, y1) - eps <= v <= max(y0, y1) + eps (v integer: ceil / floor)
    first = max(vmin, int(np.ceil(min(y0, y1) - eps)))
    last = min(vmax, int(np.floor(max(y0, y1) + eps)))
    first = (first + row_step - 1) // row_step * row_step     # (first >= vmin >= 0)
    for v in range(first, last + 1, row_step):
        y = float(v)
        x = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
        lo[v - vmin] = min(lo[v - vmin], x)
        hi[v - vmin] = max(hi[v - vmin], x)


@njit(cache=True, nogil=True)
def rasterize_triangles(vertices, triangles, height, width):
    """int32 (height, width) map: index of the triangle containing each pixel centre, or -1.

    For every pixel row the triangle's column span is found from its edges (each edge
    visits only the rows it crosses), so the work is proportional to the covered area.
    """
    tri_map = np.empty((height, width), dtype=np.int32)
    _rasterize_into(vertices, triangles, tri_map, 1)
    return tri_map


def rasterize_triangles_into(vertices, triangles, tri_map, *, row_step: int = 1) -> None:
    """:func:`rasterize_triangles` into an existing int32 (height, width) map (its
    previous contents are overwritten), on the rows ``v`` that are a multiple of
    ``row_step`` (subsampled matching reads only those; the other rows are left as they
    were). A ``row_step`` below 1 raises :class:`~canopy_stereo.errors.CanopyStereoError`
    (no row would be written)."""
    if int(row_step) < 1:
        raise CanopyStereoError(f"row_step must be 1 or more (every row_step-th row is "
                                f"rasterised), got {row_step}")
    _rasterize_into(vertices, triangles, tri_map, int(row_step))


@njit(cache=True, nogil=True)
def _rasterize_into(vertices, triangles, tri_map, row_step):
    """:func:`rasterize_triangles_into`: float64 (N, 2) ``vertices``, int32 (T, 3)
    ``triangles``, int32 (H, W) ``tri_map`` written on rows ``0, row_step, ..``."""
    if row_step == 1:       # (a constant step: the loops compiled for it, as fast as before)
        _rasterize_rows(vertices, triangles, tri_map, 1)
    else:
        _rasterize_rows(vertices, triangles, tri_map, row_step)


@njit(cache=True, inline="always")
def _rasterize_rows(vertices, triangles, tri_map, row_step):
    """The body of :func:`rasterize_triangles_into` (inlined, so that a constant
    ``row_step`` is compiled in)."""
    height, width = tri_map.shape
    for v in range(0, height, row_step):
        tri_map[v, :] = -1
    eps = 1e-9
    lo = np.empty(height, dtype=np.float64)
    hi = np.empty(height, dtype=np.float64)
    for t in range(triangles.shape[0]):
        ax = vertices[triangles[t, 0], 0]
        ay = vertices[triangles[t, 0], 1]
        bx = vertices[triangles[t, 1], 0]
        by = vertices[triangles[t, 1], 1]
        cx = vertices[triangles[t, 2], 0]
        cy = vertices[triangles[t, 2], 1]
        vmin = int(np.ceil(min(ay, by, cy) - eps))
        vmax = int(np.floor(max(ay, by, cy) + eps))
        vmin = max(vmin, 0)
        vmax = min(vmax, height - 1)
        if vmin > vmax:
            continue
        first = (vmin + row_step - 1) // row_step * row_step
        for k in range(first - vmin, vmax - vmin + 1, row_step):
            lo[k] = np.inf
            hi[k] = -np.inf
        _edge_span(ax, ay, bx, by, vmin, vmax, lo, hi, eps, row_step)
        _edge_span(bx, by, cx, cy, vmin, vmax, lo, hi, eps, row_step)
        _edge_span(cx, cy, ax, ay, vmin, vmax, lo, hi, eps, row_step)
        for v in range(first, vmax + 1, row_step):
            if lo[v - vmin] > hi[v - vmin]:
                continue
            u0 = max(int(np.ceil(lo[v - vmin] - eps)), 0)
            u1 = min(int(np.floor(hi[v - vmin] + eps)), width - 1)
            if u1 >= u0:        # (a slice fill, ~8 % faster than a loop; u1 may be < -1)
                tri_map[v, u0:u1 + 1] = t
