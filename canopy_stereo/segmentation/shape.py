"""3D shape cues of a plant mask, from a depth cue registered to the image.

Everything works on an *inverse depth* map ``q`` (high = near): a disparity
as it is, or ``Q_SCALE * median(z) / z`` of a depth map or of the camera-frame
depth of an organized cloud (:func:`inverse_depth`). In ``(u, v, q)`` a 3D
plane is a plane (``q = a u + b v + c``), so backdrops, walls, table tops and
tray surfaces are found by RANSAC in the image itself (:func:`fit_planes`).

What stands off those planes is a plant or an object. Plants are thin: leaves
and stems a few pixels to a few tens of pixels across at different depths,
so the depth around a plant pixel is rough (a local plane fits it badly, or
part of the window has no depth). Pots, cans, boxes are smooth solids: the
depth is locally planar over wide windows (:func:`local_roughness`), and they
stand on the ground: a smooth region that touches the ground plane (or the
image's bottom edge) is a solid object (:func:`grounded_solids`).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError

#: Median inverse depth of a depth map or cloud (so its noise reads like a disparity's pixels).
Q_SCALE = 50.0


def inverse_depth(*, disparity=None, points=None, depth=None, camera=None) -> np.ndarray:
    """Inverse-depth map ``q`` (float64 (H, W), high = near, NaN = unknown).

    Args:
        disparity: (H, W) disparity in pixels (negative or non-finite = unknown), used as it is.
        points: (H, W, 3) organized cloud on the image grid (world units, NaN = unknown).
        depth: (H, W) depth or distance (low = near; non-positive or non-finite = unknown).
        camera: (3, 4) ``P`` of the image's camera for ``points`` (the depth is then the
            camera-frame z); None: the distance from the cloud's own estimated camera centre
            is used, or, when that cannot be told, the cloud's z.
    """
    given = [a is not None for a in (disparity, points, depth)]
    if sum(given) != 1:
        raise ImageError("give exactly one depth cue: a disparity, an organized cloud or a depth map")
    if disparity is not None:
        q = np.asarray(disparity, np.float64).copy()
        q[~(q >= 0)] = np.nan
        return q
    if points is not None:
        X = np.asarray(points, np.float64)
        if X.ndim != 3 or X.shape[2] != 3:
            raise ImageError(f"an organized cloud must be (H, W, 3), got shape {X.shape}")
        z = _camera_depth(X, camera)
    else:
        z = np.asarray(depth, np.float64)
        if z.ndim == 3:
            z = z[..., 0]
    z = np.where(np.isfinite(z) & (z > 0), z, np.nan)
    if not np.isfinite(z).any():
        raise ImageError("the depth cue has no valid value")
    return Q_SCALE * float(np.nanmedian(z)) / z


def _camera_depth(X: np.ndarray, camera) -> np.ndarray:
    """Depth of each point along the camera's optical axis (or its distance from the centre)."""
    if camera is not None:
        P = np.asarray(camera, np.float64).reshape(3, 4)
        M = P[:, :3]
        C = -np.linalg.solve(M, P[:, 3])
        axis = M[2] / np.linalg.norm(M[2]) * np.sign(np.linalg.det(M))
        return (X - C) @ axis
    finite = np.all(np.isfinite(X), axis=-1)
    vs, us = np.nonzero(finite)
    if len(vs) >= 12:
        from canopy_stereo.geometry.calibration import dlt_projection

        pick = np.random.default_rng(0).choice(len(vs), min(600, len(vs)), replace=False)
        try:
            P = dlt_projection(X[vs[pick], us[pick]], np.stack([us[pick], vs[pick]], 1).astype(np.float64))
            return _camera_depth(X, P)
        except (ValueError, np.linalg.LinAlgError, CanopyStereoError):
            pass
    return X[..., 2]


@dataclass
class Plane:
    """A plane of the inverse-depth map: ``q = a u + b v + c`` and its inlier pixels."""

    coeffs: np.ndarray
    inliers: np.ndarray

    def residual(self, q: np.ndarray) -> np.ndarray:
        h, w = q.shape
        v, u = np.mgrid[0:h, 0:w]
        a, b, c = self.coeffs
        return q - (a * u + b * v + c)

    def is_ground(self, q_median: float, height: int) -> bool:
        """Whether the plane is seen from above (a floor, table, bench): ``q`` grows down the
        image by more than 30 % of its median over the image height."""
        return bool(self.coeffs[1] * height > 0.3 * q_median)


def fit_planes(q: np.ndarray, *, tolerance: float, min_fraction: float = 0.06, max_planes: int = 4,
               iterations: int = 200, seed: int = 0) -> list[Plane]:
    """Dominant planes of an inverse-depth map, peeled off one after another by RANSAC.

    Each hypothesis is drawn from three pixels close together (within 1/8 of the
    image width), so it comes from one surface; a plane's inliers are the
    connected regions of pixels within ``tolerance`` that cover at least 1 % of the
    image (a plane through scattered leaves is not a surface), and little of the scene
    may lie behind it (at most 10 % of its inliers' count more than 3 tolerances
    behind): backdrops, walls, floors and tables bound the scene, a plane through
    the objects in front of them does not. Hypotheses with more of the scene behind
    them are not scored (so a plane through the objects cannot win the draw and take
    the pixels of the wall behind them with it).

    Args:
        q: (H, W) inverse depth (NaN = unknown).
        tolerance: inlier distance in ``q`` units.
        min_fraction: a plane needs inliers on at least this fraction of the valid pixels.
        max_planes: most planes returned.
    """
    h, w = q.shape
    v, u = np.mgrid[0:h, 0:w]
    free = np.isfinite(q)
    n_valid = int(free.sum())
    rng = np.random.default_rng(seed)
    reach = max(4, w // 8)
    planes: list[Plane] = []
    for _ in range(max_planes + 6):
        if len(planes) >= max_planes:
            break
        idx = np.flatnonzero(free)
        if len(idx) < max(50, min_fraction * n_valid):
            break
        sample = idx if len(idx) <= 6000 else rng.choice(idx, 6000, replace=False)
        su, sv = u.ravel()[sample], v.ravel()[sample]
        A = np.stack([su, sv, np.ones(len(sample))], 1).astype(np.float64)
        b = q.ravel()[sample]
        best, best_count = None, 0
        for _ in range(iterations):
            first = rng.integers(len(sample))
            near = np.flatnonzero((np.abs(su - su[first]) < reach) & (np.abs(sv - sv[first]) < reach))
            if len(near) < 3:
                continue
            pick = rng.choice(near, 3, replace=False)
            try:
                coeffs = np.linalg.solve(A[pick], b[pick])
            except np.linalg.LinAlgError:
                continue
            off = b - A @ coeffs
            count = int(np.sum(np.abs(off) < tolerance))
            if count > best_count and np.sum(off < -3 * tolerance) <= 0.1 * count:
                best, best_count = coeffs, count
        if best is None:
            break
        for _ in range(2):  # least squares on the inliers
            inl = np.abs(A @ best - b) < tolerance
            if inl.sum() < 3:
                break
            best = np.linalg.lstsq(A[inl], b[inl], rcond=None)[0]
        with np.errstate(invalid="ignore"):
            off = q - (best[0] * u + best[1] * v + best[2])
            close = free & (np.abs(off) < tolerance)
            behind = int(np.sum(off < -3 * tolerance))
        n, lab, stats, _ = cv2.connectedComponentsWithStats(close.astype(np.uint8), connectivity=8)
        big = stats[:, cv2.CC_STAT_AREA] >= 0.01 * h * w
        big[0] = False
        inliers = big[lab]
        free &= ~close
        if inliers.sum() >= min_fraction * n_valid and behind <= 0.1 * inliers.sum():
            planes.append(Plane(best, inliers))
    return planes


def fit_ground(q: np.ndarray, free: np.ndarray, *, tolerance: float, iterations: int = 300,
               seed: int = 1) -> Plane | None:
    """A ground plane (a table, a bench, a floor: ``q`` growing down the image) among the
    ``free`` pixels of the lower 40 % of the image, when :func:`fit_planes` found none.

    Hypotheses are drawn from three pixels anywhere in that band (a table seen in pieces
    between pots holds together), only planes seen from above with little of the band
    behind them (at most 10 % of their inliers' count more than 3 tolerances behind: the
    objects stand on the ground, a slanted plane through their fronts has the table
    behind it) are scored, and the inliers must cover at least 2 % of the valid pixels in regions of 0.5 % of the image.
    """
    h, w = q.shape
    v, u = np.mgrid[0:h, 0:w]
    valid = np.isfinite(q)
    band = free & valid & (v >= 0.6 * h)
    idx = np.flatnonzero(band)
    if len(idx) < 50:
        return None
    rng = np.random.default_rng(seed)
    sample = idx if len(idx) <= 4000 else rng.choice(idx, 4000, replace=False)
    A = np.stack([u.ravel()[sample], v.ravel()[sample], np.ones(len(sample))], 1).astype(np.float64)
    b = q.ravel()[sample]
    qmed = float(np.nanmedian(q))
    best, best_count = None, 0
    for _ in range(iterations):
        pick = rng.choice(len(sample), 3, replace=False)
        try:
            coeffs = np.linalg.solve(A[pick], b[pick])
        except np.linalg.LinAlgError:
            continue
        if not coeffs[1] * h > 0.3 * qmed:
            continue
        off = b - A @ coeffs
        count = int(np.sum(np.abs(off) < tolerance))
        if count > best_count and np.sum(off < -3 * tolerance) <= 0.1 * count:
            best, best_count = coeffs, count
    if best is None:
        return None
    inl = np.abs(A @ best - b) < tolerance
    if inl.sum() >= 3:
        best = np.linalg.lstsq(A[inl], b[inl], rcond=None)[0]
    with np.errstate(invalid="ignore"):
        close = free & valid & (np.abs(q - (best[0] * u + best[1] * v + best[2])) < tolerance)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(close.astype(np.uint8), connectivity=8)
    big = stats[:, cv2.CC_STAT_AREA] >= 0.005 * h * w
    big[0] = False
    inliers = big[lab]
    plane = Plane(best, inliers)
    if inliers.sum() < 0.02 * valid.sum() or not plane.is_ground(qmed, h):
        return None
    return plane


def local_roughness(q: np.ndarray, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """RMS residual of a least-squares plane fitted to ``q`` in each (2 radius + 1)^2 window,
    and the fraction of the window without depth. Returns ``(rms (H, W), missing (H, W))``;
    ``rms`` is inf where fewer than 6 pixels of the window have depth."""
    valid = np.isfinite(q)
    w = valid.astype(np.float64)
    qq = np.where(valid, q, 0.0)
    h, wd = q.shape
    v, u = np.mgrid[0:h, 0:wd].astype(np.float64)
    k = (2 * radius + 1, 2 * radius + 1)

    def box(a):
        return cv2.boxFilter(a, cv2.CV_64F, k, normalize=False, borderType=cv2.BORDER_CONSTANT)

    n = box(w)
    su, sv, sq = box(w * u), box(w * v), box(qq)
    suu, suv, svv = box(w * u * u), box(w * u * v), box(w * v * v)
    suq, svq, sqq = box(u * qq), box(v * qq), box(qq * qq)
    with np.errstate(invalid="ignore", divide="ignore"):
        mu, mv, mq = su / n, sv / n, sq / n
        cuu, cuv, cvv = suu / n - mu * mu, suv / n - mu * mv, svv / n - mv * mv
        cuq, cvq, cqq = suq / n - mu * mq, svq / n - mv * mq, sqq / n - mq * mq
        det = cuu * cvv - cuv * cuv
        explained = (cvv * cuq * cuq - 2 * cuv * cuq * cvq + cuu * cvq * cvq) / det
        rms = np.sqrt(np.clip(cqq - explained, 0, None))
    rms[~(n >= 6) | ~np.isfinite(rms)] = np.inf
    missing = 1.0 - n / float(k[0] * k[1])
    return rms, missing


def jump_edges(q: np.ndarray, jump: float) -> np.ndarray:
    """Pixels next to a depth jump larger than ``jump`` (or next to a pixel without depth)."""
    qf = np.where(np.isfinite(q), q, -1e9)
    out = np.zeros(q.shape, bool)
    for dv, du in ((0, 1), (1, 0)):
        a = qf[: q.shape[0] - dv, : q.shape[1] - du]
        b = qf[dv:, du:]
        big = np.abs(a - b) > jump
        out[: q.shape[0] - dv, : q.shape[1] - du] |= big
        out[dv:, du:] |= big
    return out


def grounded_solids(smooth: np.ndarray, contact: np.ndarray, *, min_pixels: int) -> np.ndarray:
    """Smooth regions (8-connected components of ``smooth``) of at least ``min_pixels``
    that touch ``contact`` (pixels just above the ground plane, or the image's bottom rows)."""
    n, lab = cv2.connectedComponents(smooth.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(smooth.shape, bool)
    sizes = np.bincount(lab.ravel(), minlength=n)
    touching = np.zeros(n, bool)
    touching[np.unique(lab[contact & smooth])] = True
    touching[0] = False
    return (touching & (sizes >= min_pixels))[lab]


def edge_density(image_bgr: np.ndarray, radius: int, *, low: int = 40, high: int = 100) -> np.ndarray:
    """Fraction of Canny edge pixels (thresholds ``low``, ``high`` on the grey image) in each
    (2 radius + 1)^2 window: the texture energy of foliage (many leaf outlines and veins)
    against the plain surfaces of pots, cans and boxes."""
    grey = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY) if image_bgr.ndim == 3 else image_bgr
    edges = (cv2.Canny(grey, low, high) > 0).astype(np.float32)
    return cv2.boxFilter(edges, cv2.CV_32F, (2 * radius + 1, 2 * radius + 1), borderType=cv2.BORDER_REFLECT)


def attached_parts(solids: np.ndarray, q: np.ndarray, allowed: np.ndarray, *, jump: float,
                   reach: int) -> np.ndarray:
    """Pixels reached from ``solids`` through ``allowed`` pixels without a depth jump above
    ``jump`` between 4-neighbours, within ``reach`` steps: the handle, spout and rim of a
    solid object, thin themselves but continuous with its body."""
    out = solids.copy()
    qf = np.where(np.isfinite(q), q, np.nan)
    frontier = solids.copy()
    for _ in range(int(reach)):
        grown = np.zeros_like(frontier)
        for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            src = np.roll(frontier, (dv, du), axis=(0, 1))
            qs = np.roll(qf, (dv, du), axis=(0, 1))
            with np.errstate(invalid="ignore"):
                grown |= src & (np.abs(qs - qf) <= jump)
        grown &= allowed & ~out
        if not grown.any():
            break
        out |= grown
        frontier = grown
    return out


def caps(solids: np.ndarray, *, fraction: float = 0.3) -> np.ndarray:
    """The band above each column of each solid region, ``fraction`` of the region's width
    high: where the soil in a pot (or whatever lies on the object) is seen."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(solids.astype(np.uint8), connectivity=8)
    out = np.zeros(solids.shape, bool)
    rows = np.arange(solids.shape[0])[:, None]
    for i in range(1, n):
        x, w = stats[i, cv2.CC_STAT_LEFT], stats[i, cv2.CC_STAT_WIDTH]
        part = lab[:, x:x + w] == i
        has = part.any(axis=0)
        top = np.where(has, part.argmax(axis=0), solids.shape[0])
        band = max(2, int(fraction * w))
        out[:, x:x + w] |= (rows < top[None, :]) & (rows >= top[None, :] - band) & has[None, :]
    return out


def solids_behind(candidates: np.ndarray, solids: np.ndarray, q: np.ndarray, *, min_pixels: int,
                  ratio: float = 0.92, gap: int = 3) -> np.ndarray:
    """Components of ``candidates`` (smooth plain regions) of at least ``min_pixels`` that touch a
    solid (within ``gap`` pixels) and lie behind it (median inverse depth below ``ratio`` times the
    solid's): a box whose foot the watering can in front of it hides."""
    n, lab = cv2.connectedComponents((candidates & ~solids).astype(np.uint8), connectivity=8)
    if n <= 1 or not solids.any():
        return np.zeros(solids.shape, bool)
    ns, slab = cv2.connectedComponents(solids.astype(np.uint8), connectivity=8)
    k = np.ones((2 * gap + 1, 2 * gap + 1), np.uint8)
    out = np.zeros(solids.shape, bool)
    for i in range(1, n):
        region = lab == i
        if region.sum() < min_pixels:
            continue
        ring = cv2.dilate(region.astype(np.uint8), k).astype(bool) & solids
        if not ring.any():
            continue
        q_region = np.nanmedian(q[region])
        for j in np.unique(slab[ring]):
            if q_region < ratio * np.nanmedian(q[slab == j]):
                out |= region
                break
    return out


def standing_out(lead: np.ndarray, margin: float) -> np.ndarray:
    """Pixels more than ``margin`` in front of every plane (``lead``: the smallest plane residual)
    in regions that stand out as a whole (median lead above ``margin``): seedlings a few
    millimetres above their tray, not the speckle of matching noise around a plane."""
    front = np.isfinite(lead) & (lead > margin)
    n, lab = cv2.connectedComponents(front.astype(np.uint8), connectivity=8)
    if n <= 1:
        return front
    sums = np.bincount(lab.ravel(), weights=np.where(front, lead, 0.0).ravel(), minlength=n)
    counts = np.bincount(lab.ravel(), minlength=n)
    # mean lead of each region against the margin, over the region grown by its halo of noise
    grown = cv2.dilate(lab.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
    halo = (grown > 0) & ~front & np.isfinite(lead)
    hs = np.bincount(grown[halo], weights=lead[halo], minlength=n)
    hc = np.bincount(grown[halo], minlength=n)
    mean = (sums + hs) / np.maximum(counts + hc, 1)
    ok = mean > margin
    ok[0] = False
    return ok[lab]
