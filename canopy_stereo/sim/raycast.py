"""Exact ray casting of the analytic primitives (numba kernels).

A scene is packed into flat arrays (:class:`PackedScene`): per primitive its
kind code, local frame (``axes`` rows, ``origin``), geometry row and material
row (see :mod:`canopy_stereo.sim.primitives`). Rays are intersected with each
surface in the primitive's local frame by solving the quadric (or plane)
equation in closed form, so the hit points are exact to floating point.

Image rendering (:func:`trace_image`) casts, for every pixel, the rays through
a fixed pattern of sub-pixel samples (sample 0 is the pixel centre and gives
the ground truth point and primitive of the pixel); the radiance of the pixel
is the weighted mean of the samples' radiance. Rays come from the pinhole
``P = [M | p4]`` as ``d ~ M^-1 (u, v, 1)`` at *ideal* (undistorted) pixel
positions of the samples. To keep the work per ray small, the image is cut
into square tiles and each tile only tests the primitives whose projected
bounding box overlaps the tile (:func:`bin_primitives`). The kernels release
the GIL, so the two views of a pair render on two threads.

Note on numba's on-disk cache: a kernel's cache is keyed by its own file, so
after editing :mod:`canopy_stereo.sim.textures` (whose functions are compiled
into :func:`trace_image`) delete ``canopy_stereo/sim/__pycache__``.

Shading is Lambertian and two-sided: ``albedo * (ambient + diffuse * |n . L|)``
for a directional light ``L``; it does not depend on the viewing direction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from canopy_stereo.sim.primitives import (
    N_GEOMETRY_PARAMS,
    PRIM_CYLINDER,
    PRIM_DISC,
    PRIM_FRUSTUM,
    PRIM_LEAF,
    PRIM_SPHERE,
    local_corners,
)
from canopy_stereo.sim.textures import N_MATERIAL_PARAMS, albedo

#: Rays hit nothing closer than this many world units to their origin.
T_MIN = 1e-9


@dataclass(frozen=True)
class PackedScene:
    """Flat arrays of a scene's primitives for the kernels.

    Attributes:
        kinds: (P,) int64 primitive kind codes.
        axes: (P, 3, 3) local axes (rows) in world coordinates.
        origins: (P, 3) local frame origins (world units).
        geometry: (P, 8) geometry rows.
        materials: (P, 8) material rows (kind, seed, 6 parameters).
        corners: (P, 8, 3) world corners of each local bounding box (inf allowed).
        bounds_lo, bounds_hi: (P, 3) local bounding box of each primitive.
        leaf_ids: (P,) int32 leaf id of each primitive (0 for non-leaves).
        labels: (P,) uint8 pixel class of each primitive.
    """

    kinds: np.ndarray
    axes: np.ndarray
    origins: np.ndarray
    geometry: np.ndarray
    materials: np.ndarray
    corners: np.ndarray
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    leaf_ids: np.ndarray
    labels: np.ndarray

    @classmethod
    def from_primitives(cls, primitives) -> PackedScene:
        n = len(primitives)
        geometry = np.zeros((n, N_GEOMETRY_PARAMS))
        for i, p in enumerate(primitives):
            g = p.geometry()
            geometry[i, :len(g)] = g
        return cls(
            kinds=np.array([p.kind for p in primitives], np.int64),
            axes=np.array([p.axes for p in primitives], np.float64).reshape(n, 3, 3),
            origins=np.array([p.origin for p in primitives], np.float64).reshape(n, 3),
            geometry=geometry,
            materials=np.array([p.material.row() for p in primitives], np.float64).reshape(
                n, 2 + N_MATERIAL_PARAMS),
            corners=np.array([local_corners(p) for p in primitives], np.float64).reshape(n, 8, 3),
            bounds_lo=np.array([p.local_bounds()[0] for p in primitives], np.float64).reshape(n, 3),
            bounds_hi=np.array([p.local_bounds()[1] for p in primitives], np.float64).reshape(n, 3),
            leaf_ids=np.array([getattr(p, "leaf_id", 0) for p in primitives], np.int32),
            labels=np.array([p.label for p in primitives], np.uint8),
        )

    def local_origins(self, centre) -> np.ndarray:
        """(P, 3) a camera centre in every primitive's local frame."""
        return np.einsum("pij,pj->pi", self.axes, np.asarray(centre, np.float64) - self.origins)

    def near_distances(self, centre) -> np.ndarray:
        """(P,) lower bound of the distance from ``centre`` to each primitive:
        the distance to its local bounding box (0 when inside)."""
        o = self.local_origins(centre)
        return np.linalg.norm(o - np.clip(o, self.bounds_lo, self.bounds_hi), axis=1)


# ----------------------------------------------------------------------------- kernels


@njit(cache=True)
def _quadratic_roots(A, B, C):
    """Real roots ``t0 <= t1`` of ``A t^2 + B t + C`` (NaN when none)."""
    if A == 0.0:
        if B == 0.0:
            return np.nan, np.nan
        t = -C / B
        return t, np.nan
    disc = B * B - 4.0 * A * C
    if disc < 0.0:
        return np.nan, np.nan
    sq = math.sqrt(disc)
    q = -0.5 * (B + sq) if B >= 0.0 else -0.5 * (B - sq)
    t0 = q / A
    t1 = C / q if q != 0.0 else t0
    if t0 > t1:
        return t1, t0
    return t0, t1


@njit(cache=True)
def _leaf_half_width(x, g):
    s = x / g[0]
    if s <= 0.0 or s >= 1.0:
        return -1.0
    return g[1] * math.exp(g[2] * math.log(s) + g[3] * math.log(1.0 - s)) / g[4]


@njit(cache=True)
def intersect(kind, ox, oy, oz, dx, dy, dz, g):
    """Smallest ray parameter ``t > T_MIN`` of the hit with one primitive (local
    frame ray ``o + t d``), or ``inf`` when the ray misses it."""
    t0 = np.nan
    t1 = np.nan
    if kind == PRIM_LEAF:
        kx = g[5]
        gx = g[6]
        ky = g[7]
        A = kx * dx * dx + ky * dy * dy
        B = 2.0 * kx * ox * dx + gx * dx + 2.0 * ky * oy * dy - dz
        C = kx * ox * ox + gx * ox + ky * oy * oy - oz
        t0, t1 = _quadratic_roots(A, B, C)
        for t in (t0, t1):
            if t > T_MIN:
                x = ox + t * dx
                hw = _leaf_half_width(x, g)
                if hw > 0.0 and abs(oy + t * dy) <= hw:
                    return t
        return np.inf
    if kind == PRIM_CYLINDER:
        r = g[0]
        A = dx * dx + dy * dy
        B = 2.0 * (ox * dx + oy * dy)
        C = ox * ox + oy * oy - r * r
        t0, t1 = _quadratic_roots(A, B, C)
        for t in (t0, t1):
            if t > T_MIN:
                z = oz + t * dz
                if 0.0 <= z <= g[1]:
                    return t
        return np.inf
    if kind == PRIM_SPHERE:
        r = g[0]
        A = dx * dx + dy * dy + dz * dz
        B = 2.0 * (ox * dx + oy * dy + oz * dz)
        C = ox * ox + oy * oy + oz * oz - r * r
        t0, t1 = _quadratic_roots(A, B, C)
        if t0 > T_MIN:
            return t0
        if t1 > T_MIN:
            return t1
        return np.inf
    if kind == PRIM_FRUSTUM:
        r0 = g[0]
        h = g[2]
        k = (g[1] - r0) / h
        rz = r0 + k * oz
        A = dx * dx + dy * dy - k * k * dz * dz
        B = 2.0 * (ox * dx + oy * dy - k * rz * dz)
        C = ox * ox + oy * oy - rz * rz
        t0, t1 = _quadratic_roots(A, B, C)
        for t in (t0, t1):
            if t > T_MIN:
                z = oz + t * dz
                if 0.0 <= z <= h:
                    return t
        return np.inf
    # planar: disc, or (any other kind) rectangle
    if dz == 0.0:
        return np.inf
    t = -oz / dz
    if t <= T_MIN:
        return np.inf
    x = ox + t * dx
    y = oy + t * dy
    if kind == PRIM_DISC:
        if x * x + y * y <= g[0] * g[0]:
            return t
        return np.inf
    if abs(x) <= g[0] and abs(y) <= g[1]:
        return t
    return np.inf


@njit(cache=True)
def surface_attributes(kind, x, y, z, g):
    """Local normal (unnormalised), texture coordinates and relative blade
    position at the local surface point ``(x, y, z)``."""
    if kind == PRIM_LEAF:
        hw = _leaf_half_width(x, g)
        rel = abs(y) / hw if hw > 0.0 else 1.0
        return -(2.0 * g[5] * x + g[6]), -2.0 * g[7] * y, 1.0, x, y, min(rel, 1.0)
    if kind == PRIM_CYLINDER:
        return x, y, 0.0, g[0] * math.atan2(y, x), z, 0.0
    if kind == PRIM_SPHERE:
        r = g[0]
        return x, y, z, r * math.atan2(y, x), r * math.acos(max(-1.0, min(1.0, z / r))), 0.0
    if kind == PRIM_FRUSTUM:
        k = (g[1] - g[0]) / g[2]
        rz = g[0] + k * z
        return x, y, -k * rz, rz * math.atan2(y, x), z, 0.0
    return 0.0, 0.0, 1.0, x, y, 0.0


@njit(cache=True, nogil=True)
def trace_image(height, width, tile_size, offsets, weights, ideal_uv, use_map, Minv, centre,
                tile_start, tile_prims, near, kinds, axes, local_origin, geometry, materials,
                light, ambient, diffuse, mm_per_unit, radiance, xyz, prim_index):
    """Render one view into ``radiance`` (H, W, 3) float32, ``xyz`` (H, W, 3) and
    ``prim_index`` (H, W) (the primitive hit by the pixel-centre ray, -1 none).

    Args:
        offsets: (S, 2) sub-pixel sample offsets (sample 0 = (0, 0), the centre).
        weights: (S,) sample weights summing to 1 (a zero weight is traced, not shaded).
        ideal_uv: (H, W, S, 2) ideal pixel of each sample when ``use_map`` (lens
            distortion), else unused and the ideal pixel is ``(u, v) + offset``.
        Minv: (3, 3) inverse of ``P[:, :3]`` (sign fixed so rays point forward).
        centre: (3,) camera centre, world units.
        tile_start, tile_prims: CSR lists of candidate primitives per tile, each
            sorted by ``near`` so the search stops at the first candidate that
            cannot be closer than the best hit so far.
        near: (P,) lower bound of each primitive's distance from the camera centre.
        local_origin: (P, 3) the camera centre in each primitive's frame.
        light: (3,) unit direction towards the light; ambient, diffuse: shading weights.
        mm_per_unit: millimetres per world unit (textures are sized in mm).
    """
    n_tx = (width + tile_size - 1) // tile_size
    n_ty = (height + tile_size - 1) // tile_size
    n_samples = offsets.shape[0]
    for tile in range(n_tx * n_ty):
        ty = tile // n_tx
        tx = tile - ty * n_tx
        j0 = tile_start[tile]
        j1 = tile_start[tile + 1]
        for v in range(ty * tile_size, min(height, (ty + 1) * tile_size)):
            for u in range(tx * tile_size, min(width, (tx + 1) * tile_size)):
                acc_r = 0.0
                acc_g = 0.0
                acc_b = 0.0
                for s in range(n_samples):
                    if use_map:
                        iu = ideal_uv[v, u, s, 0]
                        iv = ideal_uv[v, u, s, 1]
                    else:
                        iu = u + offsets[s, 0]
                        iv = v + offsets[s, 1]
                    if s == 0:
                        prim_index[v, u] = -1
                        xyz[v, u, 0] = np.nan
                        xyz[v, u, 1] = np.nan
                        xyz[v, u, 2] = np.nan
                    if not (np.isfinite(iu) and np.isfinite(iv)):
                        continue
                    wx = Minv[0, 0] * iu + Minv[0, 1] * iv + Minv[0, 2]
                    wy = Minv[1, 0] * iu + Minv[1, 1] * iv + Minv[1, 2]
                    wz = Minv[2, 0] * iu + Minv[2, 1] * iv + Minv[2, 2]
                    nrm = math.sqrt(wx * wx + wy * wy + wz * wz)
                    wx /= nrm
                    wy /= nrm
                    wz /= nrm
                    best_t = np.inf
                    best_k = -1
                    for j in range(j0, j1):
                        k = tile_prims[j]
                        if near[k] >= best_t:
                            break
                        a = axes[k]
                        dx = a[0, 0] * wx + a[0, 1] * wy + a[0, 2] * wz
                        dy = a[1, 0] * wx + a[1, 1] * wy + a[1, 2] * wz
                        dz = a[2, 0] * wx + a[2, 1] * wy + a[2, 2] * wz
                        t = intersect(kinds[k], local_origin[k, 0], local_origin[k, 1],
                                      local_origin[k, 2], dx, dy, dz, geometry[k])
                        if t < best_t:
                            best_t = t
                            best_k = k
                    if best_k < 0:
                        continue
                    if s == 0:
                        prim_index[v, u] = best_k
                        xyz[v, u, 0] = centre[0] + best_t * wx
                        xyz[v, u, 1] = centre[1] + best_t * wy
                        xyz[v, u, 2] = centre[2] + best_t * wz
                    if weights[s] == 0.0:
                        continue
                    k = best_k
                    a = axes[k]
                    dx = a[0, 0] * wx + a[0, 1] * wy + a[0, 2] * wz
                    dy = a[1, 0] * wx + a[1, 1] * wy + a[1, 2] * wz
                    dz = a[2, 0] * wx + a[2, 1] * wy + a[2, 2] * wz
                    lx = local_origin[k, 0] + best_t * dx
                    ly = local_origin[k, 1] + best_t * dy
                    lz = local_origin[k, 2] + best_t * dz
                    nx, ny, nz, tu, tv, rel = surface_attributes(kinds[k], lx, ly, lz, geometry[k])
                    # local normal -> world: n_w = axes^T n_l
                    gx = a[0, 0] * nx + a[1, 0] * ny + a[2, 0] * nz
                    gy = a[0, 1] * nx + a[1, 1] * ny + a[2, 1] * nz
                    gz = a[0, 2] * nx + a[1, 2] * ny + a[2, 2] * nz
                    gn = math.sqrt(gx * gx + gy * gy + gz * gz)
                    lam = abs(gx * light[0] + gy * light[1] + gz * light[2]) / gn
                    m = materials[k]
                    r, g, b = albedo(np.int64(m[0]), np.int64(m[1]), m[2:], tu * mm_per_unit,
                                     tv * mm_per_unit, geometry[k], rel, mm_per_unit)
                    shade = weights[s] * (ambient + diffuse * lam)
                    acc_r += r * shade
                    acc_g += g * shade
                    acc_b += b * shade
                radiance[v, u, 0] = acc_r
                radiance[v, u, 1] = acc_g
                radiance[v, u, 2] = acc_b


@njit(cache=True, nogil=True)
def trace_rays(origins, directions, kinds, axes, origins_prim, geometry):
    """First hit of arbitrary rays: ``(t, prim_index)`` per ray (inf / -1 when none).

    ``origins`` (N, 3) and unit ``directions`` (N, 3) in world coordinates;
    every primitive is tested (no culling): for visibility checks.
    """
    n = origins.shape[0]
    t_out = np.full(n, np.inf)
    k_out = np.full(n, -1, np.int64)
    for i in range(n):
        best_t = np.inf
        best_k = -1
        for k in range(kinds.shape[0]):
            a = axes[k]
            px = origins[i, 0] - origins_prim[k, 0]
            py = origins[i, 1] - origins_prim[k, 1]
            pz = origins[i, 2] - origins_prim[k, 2]
            ox = a[0, 0] * px + a[0, 1] * py + a[0, 2] * pz
            oy = a[1, 0] * px + a[1, 1] * py + a[1, 2] * pz
            oz = a[2, 0] * px + a[2, 1] * py + a[2, 2] * pz
            wx = directions[i, 0]
            wy = directions[i, 1]
            wz = directions[i, 2]
            dx = a[0, 0] * wx + a[0, 1] * wy + a[0, 2] * wz
            dy = a[1, 0] * wx + a[1, 1] * wy + a[1, 2] * wz
            dz = a[2, 0] * wx + a[2, 1] * wy + a[2, 2] * wz
            t = intersect(kinds[k], ox, oy, oz, dx, dy, dz, geometry[k])
            if t < best_t:
                best_t = t
                best_k = k
        t_out[i] = best_t
        k_out[i] = best_k
    return t_out, k_out


# ----------------------------------------------------------------------------- culling


def projected_boxes(P, corners, *, margin: float = 1.0) -> np.ndarray:
    """Ideal-pixel bounding boxes (P, 4) ``[u_min, u_max, v_min, v_max]`` of the
    primitives' bounding boxes seen through ``P`` (3, 4).

    A box that is unbounded or reaches behind the camera gets infinite bounds.
    """
    P = np.asarray(P, np.float64)
    s = np.linalg.norm(P[2, :3]) * np.sign(np.linalg.det(P[:, :3]))
    Pn = P / s  # third row gives depth in world units
    n = corners.shape[0]
    boxes = np.tile(np.array([-np.inf, np.inf, -np.inf, np.inf]), (n, 1))
    with np.errstate(invalid="ignore", over="ignore"):
        x = corners @ Pn[:, :3].T + Pn[:, 3]
    finite = np.all(np.isfinite(x), axis=(1, 2))
    depth = x[..., 2]
    scale = np.max(np.abs(corners[finite]), initial=1.0) if np.any(finite) else 1.0
    ok = finite & np.all(depth > 1e-9 * scale, axis=1)
    if np.any(ok):
        uv = x[ok, :, :2] / depth[ok, :, None]
        boxes[ok] = np.column_stack([uv[..., 0].min(1) - margin, uv[..., 0].max(1) + margin,
                                     uv[..., 1].min(1) - margin, uv[..., 1].max(1) + margin])
    return boxes


def tile_boxes(ideal_uv, offsets, width: int, height: int, tile_size: int) -> np.ndarray:
    """Ideal-pixel bounds (T, 4) of the samples of each image tile (row-major tiles)."""
    n_tx = (width + tile_size - 1) // tile_size
    n_ty = (height + tile_size - 1) // tile_size
    if ideal_uv is None:
        u0 = np.arange(n_tx) * tile_size
        v0 = np.arange(n_ty) * tile_size
        u1 = np.minimum(u0 + tile_size, width) - 1
        v1 = np.minimum(v0 + tile_size, height) - 1
        omin, omax = offsets.min(axis=0), offsets.max(axis=0)
        uu0, vv0 = np.meshgrid(u0 + omin[0], v0 + omin[1])
        uu1, vv1 = np.meshgrid(u1 + omax[0], v1 + omax[1])
        return np.column_stack([uu0.ravel(), uu1.ravel(), vv0.ravel(), vv1.ravel()])
    pad_h, pad_w = n_ty * tile_size - height, n_tx * tile_size - width
    m = np.pad(ideal_uv, ((0, pad_h), (0, pad_w), (0, 0), (0, 0)), mode="edge")
    m = m.reshape(n_ty, tile_size, n_tx, tile_size, -1, 2)
    with np.errstate(invalid="ignore"):
        lo = np.nanmin(m, axis=(1, 3, 4))
        hi = np.nanmax(m, axis=(1, 3, 4))
    lo = np.where(np.isfinite(lo), lo, np.inf)  # a tile with no valid sample matches nothing
    hi = np.where(np.isfinite(hi), hi, -np.inf)
    return np.column_stack([lo[..., 0].ravel(), hi[..., 0].ravel(),
                            lo[..., 1].ravel(), hi[..., 1].ravel()])


def bin_primitives(tiles: np.ndarray, boxes: np.ndarray,
                   *, near=None) -> tuple[np.ndarray, np.ndarray]:
    """CSR candidate lists: primitives whose box overlaps each tile's box, in
    increasing order of ``near`` (P,) when given, else of index.

    Returns ``(tile_start (T + 1,), tile_prims)`` as int64 arrays.
    """
    order = np.arange(len(boxes)) if near is None else np.argsort(near, kind="stable")
    boxes = boxes[order]
    b, t = boxes[None, :, :], tiles[:, None, :]
    overlap = ((b[..., 0] <= t[..., 1]) & (b[..., 1] >= t[..., 0])
               & (b[..., 2] <= t[..., 3]) & (b[..., 3] >= t[..., 2]))
    tile_idx, prim_idx = np.nonzero(overlap)
    counts = np.bincount(tile_idx, minlength=len(tiles))
    start = np.zeros(len(tiles) + 1, np.int64)
    np.cumsum(counts, out=start[1:])
    return start, order[prim_idx].astype(np.int64)
