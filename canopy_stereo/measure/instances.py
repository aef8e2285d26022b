"""Leaf instances from a plant mask and an organized cloud.

Neighbouring pixels (4-connected) of the plant mask belong to the same leaf
unless the surface breaks between them: a depth discontinuity (their 3D
points are farther apart than ``max_jump``) or a crease (their surface
normals differ by more than ``max_angle_deg``). Connected regions of the
remaining links are the leaves; pixels cut off in tiny regions are then given
to the neighbouring leaf whose surface they continue best.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.clouds import check_cloud, check_on_grid
from canopy_stereo.measure.surface import local_linear_fit, roughness


@njit(cache=True)
def _find(parent, i):  # pragma: no cover - compiled
    root = i
    while parent[root] != root:
        root = parent[root]
    while parent[i] != root:
        nxt = parent[i]
        parent[i] = root
        i = nxt
    return root


@njit(cache=True)
def _link_components(points, normals, valid, max_jump, min_cos):  # pragma: no cover - compiled
    """Union-find over 4-neighbour links that pass the jump and crease tests."""
    h, w = valid.shape
    parent = np.arange(h * w)
    use_normals = min_cos > -1.0
    for v in range(h):
        for u in range(w):
            if not valid[v, u]:
                continue
            for k in range(2):
                v2 = v + k
                u2 = u + 1 - k
                if v2 >= h or u2 >= w or not valid[v2, u2]:
                    continue
                dx = points[v2, u2, 0] - points[v, u, 0]
                dy = points[v2, u2, 1] - points[v, u, 1]
                dz = points[v2, u2, 2] - points[v, u, 2]
                if dx * dx + dy * dy + dz * dz > max_jump * max_jump:
                    continue
                if use_normals:
                    c = (normals[v, u, 0] * normals[v2, u2, 0] + normals[v, u, 1] * normals[v2, u2, 1]
                         + normals[v, u, 2] * normals[v2, u2, 2])
                    if not (c >= min_cos):
                        continue
                a = _find(parent, v * w + u)
                b = _find(parent, v2 * w + u2)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    labels = np.zeros((h, w), np.int32)
    ids = np.zeros(h * w, np.int32)
    nxt = 0
    for v in range(h):
        for u in range(w):
            if not valid[v, u]:
                continue
            r = _find(parent, v * w + u)
            if ids[r] == 0:
                nxt += 1
                ids[r] = nxt
            labels[v, u] = ids[r]
    return labels


def neighbour_spacing(organized: np.ndarray, valid: np.ndarray) -> float:
    """Median 3D distance between 4-neighbouring valid points (world units)."""
    d = []
    for a, b, va, vb in ((organized[:, 1:], organized[:, :-1], valid[:, 1:], valid[:, :-1]),
                         (organized[1:], organized[:-1], valid[1:], valid[:-1])):
        ok = va & vb
        if ok.any():
            d.append(np.linalg.norm(a[ok] - b[ok], axis=1))
    if not d:
        return float("nan")
    return float(np.median(np.concatenate(d)))


def connected_surface_parts(organized: np.ndarray, valid: np.ndarray, max_jump: float,
                            *, normals: np.ndarray | None = None, max_angle_deg: float | None = None):
    """(H, W) int32 labels 1..n of the parts of ``valid`` joined without breaks; 0 elsewhere.

    Args:
        organized: (H, W, 3) world points.
        valid: (H, W) bool, pixels to label (their points must be finite).
        max_jump: largest 3D distance between linked neighbours (world units).
        normals: optional (H, W, 3) unit normals for the crease test.
        max_angle_deg: largest angle between linked neighbours' normals.
    """
    pts = np.ascontiguousarray(np.nan_to_num(np.asarray(organized, np.float64)))
    ok = np.ascontiguousarray(valid & np.all(np.isfinite(organized), axis=-1))
    if normals is not None and max_angle_deg is not None:
        nrm = np.ascontiguousarray(np.asarray(normals, np.float64))
        ok &= np.all(np.isfinite(nrm), axis=-1)
        min_cos = float(np.cos(np.deg2rad(max_angle_deg)))
    else:
        nrm = np.zeros((1, 1, 3))
        min_cos = -2.0
    return _link_components(pts, nrm, ok, float(max_jump), min_cos)


def largest_surface_part(organized: np.ndarray, valid: np.ndarray, *, jump_factor: float = 8.0,
                         keep_fraction: float = 0.25) -> np.ndarray:
    """Drop pieces of ``valid`` cut off from the main surface by depth jumps.

    Pixels are linked when their points are closer than ``jump_factor`` times
    the median neighbour spacing; parts with fewer than ``keep_fraction`` of
    the pixels of the largest part (e.g. background depths bled onto a leaf's
    rim by the matcher) are removed. Returns the kept (H, W) bool mask.
    """
    spacing = neighbour_spacing(organized, valid)
    if not np.isfinite(spacing) or spacing <= 0:
        return valid.copy()
    labels = connected_surface_parts(organized, valid, jump_factor * spacing)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    if counts.max() == 0:
        return valid.copy()
    keep = np.nonzero(counts >= keep_fraction * counts.max())[0]
    return np.isin(labels, keep)


def _max_neighbour_angle(normals: np.ndarray) -> np.ndarray:
    """(H, W) largest angle (degrees) between a pixel's normal and its 4-neighbours'."""
    h, w = normals.shape[:2]
    cos = np.full((h, w), 1.0)
    for a, b, _sa, _sb in (((slice(None), slice(1, None)), (slice(None), slice(None, -1)), None, None),
                         ((slice(1, None), slice(None)), (slice(None, -1), slice(None)), None, None)):
        c = np.einsum("hwk,hwk->hw", normals[a], normals[b])
        c = np.where(np.isfinite(c), c, 1.0)
        cos[a] = np.minimum(cos[a], c)
        cos[b] = np.minimum(cos[b], c)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def separate_leaves(organized: np.ndarray, plant_mask: np.ndarray, *, max_jump: float | None = None,
                    max_angle_deg: float = 35.0, max_bend_deg: float = 8.0,
                    smoothing_px: float | None = None, min_pixels: int = 50,
                    jump_factor: float = 6.0, rim_px: int = 8, neck_px: int = 4) -> np.ndarray:
    """Split a plant mask into leaf instances.

    Leaves are sheets: pixels whose normal turns by more than ``max_bend_deg``
    towards a neighbour (stems, petioles, folds and the rims of occluding
    edges) and parts of the mask narrower than ``2 neck_px + 1`` pixels
    (stems and petioles, also where matching noise hides their curvature)
    are left out of the linking, so leaves come apart where they join the
    stem; the remaining sheet pixels are linked across 4-neighbours unless the
    surface jumps (``max_jump``) or creases (``max_angle_deg``). Regions of at
    least ``min_pixels`` are the leaves; up to ``rim_px + neck_px`` pixels
    around them that were left out are given back to the adjacent leaf whose
    surface they continue.

    Args:
        organized: (H, W, 3) organized cloud (world units, NaN = none).
        plant_mask: (H, W) bool/nonzero plant mask on the same grid.
        max_jump: depth-discontinuity threshold in world units; default
            ``jump_factor`` times the median neighbour spacing of the plant.
        max_angle_deg: crease threshold between linked neighbours' normals.
        max_bend_deg: sheet threshold (see above).
        smoothing_px: scale (pixels) of the normal estimate; default 2, more
            for rough (reconstructed) clouds.
        min_pixels: smallest leaf.
        jump_factor: see ``max_jump``.
        rim_px, neck_px: see above.

    Returns:
        (H, W) int32 leaf ids 1..n ordered by decreasing size; 0 = not a leaf.
    """
    organized = check_cloud(organized)
    mask = np.asarray(plant_mask).astype(bool)
    check_on_grid(mask, organized, "plant mask")
    valid = mask & np.all(np.isfinite(organized), axis=-1)
    if valid.sum() < 3:
        raise CanopyStereoError(f"the plant mask has only {int(valid.sum())} pixels with 3D points "
                                "(need at least 3)")
    if smoothing_px is None:
        rough = roughness(organized, valid) if valid.sum() >= 16 else 0.0
        smoothing_px = float(np.clip(rough / 0.05, 2.0, 8.0)) if np.isfinite(rough) else 2.0
    X, Xu, Xv = local_linear_fit(organized, valid, valid, sigma=smoothing_px)
    n = -np.cross(Xu, Xv)
    with np.errstate(invalid="ignore", divide="ignore"):
        normals = n / np.linalg.norm(n, axis=-1, keepdims=True)
    smooth = np.where(np.all(np.isfinite(X), axis=-1)[..., None], X, organized)
    spacing = neighbour_spacing(smooth, valid)
    explicit_jump = max_jump is not None
    if max_jump is None:
        max_jump = jump_factor * spacing
    sheet = valid & (_max_neighbour_angle(normals) <= max_bend_deg)
    if neck_px > 0:
        import cv2

        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * neck_px + 1, 2 * neck_px + 1))
        sheet = cv2.erode(sheet.astype(np.uint8), k).astype(bool)
    labels = connected_surface_parts(smooth, sheet, max_jump, normals=normals, max_angle_deg=max_angle_deg)
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    big = np.nonzero(counts >= min_pixels)[0]
    order = big[np.argsort(-counts[big], kind="stable")]
    remap = np.zeros(len(counts), np.int32)
    remap[order] = np.arange(1, len(order) + 1, dtype=np.int32)
    out = remap[labels]
    # give the rim back using the raw points: smoothing blurs the depth jumps
    raw_jump = max_jump if explicit_jump else jump_factor * neighbour_spacing(organized, valid)
    return _absorb_small(organized, valid, out, raw_jump, rounds=rim_px + neck_px)


def _absorb_small(organized, valid, labels, max_jump, rounds: int = 64):
    """Give unlabelled valid pixels the label of an adjacent leaf within ``max_jump``."""
    labels = labels.copy()
    pts = np.where(valid[..., None], organized, np.inf)
    for _ in range(rounds):
        todo = valid & (labels == 0)
        if not todo.any():
            break
        changed = False
        best_d = np.full(labels.shape, np.inf)
        best_l = np.zeros_like(labels)
        for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            nl = np.zeros_like(labels)
            npnt = np.full_like(pts, np.inf)
            src_v = slice(max(dv, 0), labels.shape[0] + min(dv, 0))
            dst_v = slice(max(-dv, 0), labels.shape[0] + min(-dv, 0))
            src_u = slice(max(du, 0), labels.shape[1] + min(du, 0))
            dst_u = slice(max(-du, 0), labels.shape[1] + min(-du, 0))
            nl[dst_v, dst_u] = labels[src_v, src_u]
            npnt[dst_v, dst_u] = pts[src_v, src_u]
            with np.errstate(invalid="ignore"):
                d = np.linalg.norm(npnt - pts, axis=-1)
            better = todo & (nl > 0) & (d <= max_jump) & (d < best_d)
            best_d[better] = d[better]
            best_l[better] = nl[better]
        grow = best_l > 0
        if grow.any():
            labels[grow] = best_l[grow]
            changed = True
        if not changed:
            break
    return labels
