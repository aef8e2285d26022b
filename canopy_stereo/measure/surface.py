"""Smooth surfaces from organized clouds: local-linear fits, footprints, normals.

An organized cloud is an (H, W, 3) array of world points on the pixel grid of
the left image (pixel ``(u, v)`` at ``cloud[v, u]``, u right, v down), NaN where
there is no point. Seen from the grid, a surface is a map ``X(u, v)``; its
partial derivatives ``X_u``, ``X_v`` (world units per pixel) give the surface
element of a pixel, ``|X_u x X_v|`` (world units squared), and its normal.

:func:`local_linear_fit` fits, around every pixel of a domain, a plane
``X(p + d) ~ a + X_u d_u + X_v d_v`` to the valid points weighted by a Gaussian
of the pixel offset ``d`` (a first-order Savitzky-Golay / LOESS smoother on the
grid). It reproduces linear maps exactly, averages the matching noise of a
reconstruction, fills holes and extrapolates a little past the data, so a
leaf's surface is defined on and just beyond the whole leaf mask.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

#: Largest Gaussian scale (pixels) tried when filling holes.
MAX_SIGMA_PX = 64.0


@dataclass
class GridSurface:
    """A smoothed surface on a crop of the pixel grid.

    Attributes:
        origin: ``(v0, u0)`` of the crop's top-left pixel in the full image.
        X: (h, w, 3) fitted points (world units), NaN outside ``domain``.
        X_u, X_v: (h, w, 3) derivatives along u and v (world units per pixel).
        domain: (h, w) bool, where the fit is defined.
    """

    origin: tuple[int, int]
    X: np.ndarray
    X_u: np.ndarray
    X_v: np.ndarray
    domain: np.ndarray

    @property
    def footprint(self) -> np.ndarray:
        """(h, w) surface area of each pixel, ``|X_u x X_v|`` (world units^2)."""
        return np.linalg.norm(np.cross(self.X_u, self.X_v), axis=-1)

    @property
    def normals(self) -> np.ndarray:
        """(h, w, 3) unit normals facing the camera, ``-(X_u x X_v) / |.|``.

        With a right-handed world frame, image u to the right and v down, the
        cross product ``X_u x X_v`` points away from the camera.
        """
        n = -np.cross(self.X_u, self.X_v)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            return n / norm


def _kernels(sigma: float):
    r = int(np.ceil(3.0 * sigma))
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (x / sigma) ** 2)
    return g, g * x, g * x * x


def _filter(img: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    """Correlate ``img`` with ``ky[:, None] * kx[None, :]`` (zero outside)."""
    return cv2.sepFilter2D(img, cv2.CV_64F, kx, ky, borderType=cv2.BORDER_CONSTANT)


def _fit_at_scale(points: np.ndarray, valid: np.ndarray, sigma: float):
    """Moments and solutions of the Gaussian-weighted local-linear fit at ``sigma``.

    Returns ``(coef, ok)``: coef (h, w, 3, 3) with rows ``a, X_u, X_v`` per
    coordinate (last axis = x, y, z), and ok (h, w) where the 3x3 normal
    matrix is well conditioned (enough support in two directions).
    """
    g, gx, gxx = _kernels(sigma)
    c = valid.astype(np.float64)
    m00 = _filter(c, g, g)
    m10 = _filter(c, gx, g)   # sum g c du
    m01 = _filter(c, g, gx)   # sum g c dv
    m20 = _filter(c, gxx, g)
    m11 = _filter(c, gx, gx)
    m02 = _filter(c, g, gxx)
    f = np.where(valid[..., None], points, 0.0)
    rhs = np.empty(points.shape[:2] + (3, 3))
    for k in range(3):
        fk = np.ascontiguousarray(f[..., k])
        rhs[..., 0, k] = _filter(fk, g, g)
        rhs[..., 1, k] = _filter(fk, gx, g)
        rhs[..., 2, k] = _filter(fk, g, gx)
    A = np.stack([np.stack([m00, m10, m01], -1),
                  np.stack([m10, m20, m11], -1),
                  np.stack([m01, m11, m02], -1)], -2)
    total = g.sum() ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_u, mean_v = m10 / m00, m01 / m00
        cuu = m20 / m00 - mean_u ** 2
        cvv = m02 / m00 - mean_v ** 2
        cuv = m11 / m00 - mean_u * mean_v
        # smallest eigenvalue of the weighted offset covariance (pixels^2)
        tr, det = cuu + cvv, cuu * cvv - cuv ** 2
        lam_min = 0.5 * tr - np.sqrt(np.maximum(0.25 * tr * tr - det, 0.0))
    ok = (m00 > 0.05 * total) & (lam_min > 0.05 * sigma * sigma)
    coef = np.full(points.shape[:2] + (3, 3), np.nan)
    idx = np.nonzero(ok)
    if len(idx[0]):
        coef[idx] = np.linalg.solve(A[idx], rhs[idx])
    return coef, ok


def local_linear_fit(points: np.ndarray, valid: np.ndarray, domain: np.ndarray,
                     *, sigma: float = 2.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gaussian-weighted local-linear fit of an organized (crop of a) cloud.

    Args:
        points: (h, w, 3) world points (anything where not ``valid``).
        valid: (h, w) bool, the points that enter the fit.
        domain: (h, w) bool, where to evaluate the fit.
        sigma: Gaussian scale in pixels. Pixels of ``domain`` without enough
            valid neighbours at this scale (holes, the rim past the data) are
            fitted at 2, 4, ... times ``sigma`` (up to :data:`MAX_SIGMA_PX`).
            ``sigma <= 0`` returns the valid points as they are, with central
            (or one-sided) differences as derivatives, and NaN elsewhere.

    Returns:
        ``(X, X_u, X_v)``, each (h, w, 3), NaN outside ``domain`` and where no
        scale gave a well-posed fit.
    """
    points = np.asarray(points, np.float64)
    valid = valid & np.all(np.isfinite(points), axis=-1)
    shape = points.shape
    if sigma <= 0:
        return _raw_with_differences(points, valid, domain)
    X = np.full(shape, np.nan)
    Xu = np.full(shape, np.nan)
    Xv = np.full(shape, np.nan)
    todo = domain.copy()
    s = float(sigma)
    while todo.any() and s <= MAX_SIGMA_PX * 1.0001:
        coef, ok = _fit_at_scale(points, valid, s)
        take = todo & ok
        X[take] = coef[take][:, 0, :]
        Xu[take] = coef[take][:, 1, :]
        Xv[take] = coef[take][:, 2, :]
        todo &= ~take
        s *= 2.0
    return X, Xu, Xv


def _raw_with_differences(points, valid, domain):
    """Valid points unchanged; derivatives by central or one-sided differences."""
    X = np.where((valid & domain)[..., None], points, np.nan)
    P = np.where(valid[..., None], points, np.nan)

    def diff(axis):
        fwd = np.full_like(P, np.nan)
        bwd = np.full_like(P, np.nan)
        if axis == 1:
            fwd[:, :-1] = P[:, 1:] - P[:, :-1]
            bwd[:, 1:] = P[:, 1:] - P[:, :-1]
        else:
            fwd[:-1] = P[1:] - P[:-1]
            bwd[1:] = P[1:] - P[:-1]
        central = 0.5 * (fwd + bwd)
        out = np.where(np.isfinite(central), central, np.where(np.isfinite(fwd), fwd, bwd))
        return np.where((valid & domain)[..., None], out, np.nan)

    return X, diff(1), diff(0)


def fit_grid_surface(organized: np.ndarray, valid: np.ndarray, domain: np.ndarray,
                     *, sigma: float = 2.0) -> GridSurface:
    """Fit a :class:`GridSurface` on the bounding box of ``domain`` (plus a margin).

    Args:
        organized: (H, W, 3) organized cloud (world units, NaN = none).
        valid: (H, W) bool, the points to use (e.g. a leaf mask without outliers).
        domain: (H, W) bool, where the surface is wanted.
        sigma: smoothing scale in pixels (see :func:`local_linear_fit`).
    """
    vs, us = np.nonzero(domain)
    H, W = domain.shape
    margin = int(np.ceil(3 * max(sigma, 1.0))) + 2
    v0, v1 = max(vs.min() - margin, 0), min(vs.max() + margin + 1, H)
    u0, u1 = max(us.min() - margin, 0), min(us.max() + margin + 1, W)
    crop = (slice(v0, v1), slice(u0, u1))
    X, Xu, Xv = local_linear_fit(organized[crop], valid[crop], domain[crop], sigma=sigma)
    dom = domain[crop] & np.all(np.isfinite(X), axis=-1) & np.all(np.isfinite(Xu), axis=-1) \
        & np.all(np.isfinite(Xv), axis=-1)
    return GridSurface(origin=(int(v0), int(u0)), X=X, X_u=Xu, X_v=Xv, domain=dom)


def pixel_footprints(organized: np.ndarray) -> np.ndarray:
    """(H, W) surface area of each pixel of a raw organized cloud (world units^2).

    ``|X_u x X_v|`` with central differences (one-sided at holes and edges);
    NaN where a pixel has no point or no neighbour in some direction.
    """
    finite = np.all(np.isfinite(organized), axis=-1)
    _, Xu, Xv = _raw_with_differences(np.asarray(organized, np.float64), finite, finite)
    return np.linalg.norm(np.cross(Xu, Xv), axis=-1)


def _poly_terms(x: np.ndarray, y: np.ndarray, degree: int) -> np.ndarray:
    """(N, K) monomials ``x^i y^j`` with ``i + j <= degree`` and their count K."""
    cols = [x ** i * y ** j for i in range(degree + 1) for j in range(degree + 1 - i)]
    return np.stack(cols, axis=-1)


def _poly_terms_du(x: np.ndarray, y: np.ndarray, degree: int):
    """Derivatives of :func:`_poly_terms` along x and along y."""
    dx = [i * x ** max(i - 1, 0) * y ** j if i else np.zeros_like(x)
          for i in range(degree + 1) for j in range(degree + 1 - i)]
    dy = [j * x ** i * y ** max(j - 1, 0) if j else np.zeros_like(x)
          for i in range(degree + 1) for j in range(degree + 1 - i)]
    return np.stack(dx, axis=-1), np.stack(dy, axis=-1)


def fit_ray_surface(organized: np.ndarray, valid: np.ndarray, domain: np.ndarray, P,
                    *, degree: int = 3, iterations: int = 5) -> tuple[GridSurface, np.ndarray]:
    """Leaf surface as a smooth inverse depth along the camera's rays.

    A stereo reconstruction errs mainly along the left camera's rays (its
    error is a disparity error), so each pixel's point is modelled as
    ``X(u, v) = C + r(u, v) / w(u, v)`` with the pixel's ray
    ``r = M^-1 (u, v, 1)`` (``P = [M | p4]`` normalised so ``1/w`` is the depth
    along the optical axis) and ``w`` a polynomial of total degree ``degree``
    in ``(u, v)``, fitted to the valid points by least squares with outliers
    (beyond 3.5 robust standard deviations, and beyond half a pixel size in
    depth) removed iteratively. A plane seen
    by a pinhole camera has ``w`` linear in ``(u, v)``, so ``degree >= 1``
    reproduces flat leaves exactly; gently curved leaves need 2 or 3.

    Args:
        organized: (h, w, 3) world points (crop, with ``P`` in crop pixel
            coordinates; see :func:`shift_projection`).
        valid: (h, w) bool, points to fit.
        domain: (h, w) bool, where the surface is wanted.
        P: (3, 4) the camera that sees the grid.
        degree: polynomial degree of the inverse depth.
        iterations: rounds of outlier removal.

    Returns:
        ``(surface, inliers)``: the :class:`GridSurface` on the crop (origin 0, 0)
        and the (h, w) bool mask of the points kept by the fit.
    """
    from canopy_stereo.geometry.camera import camera_centre, normalize_projection

    Pn = normalize_projection(P)
    Minv = np.linalg.inv(Pn[:, :3])
    C = camera_centre(Pn)
    pts = np.asarray(organized, np.float64)
    valid = valid & np.all(np.isfinite(pts), axis=-1)
    vs, us = np.nonzero(valid)
    lam = pts[vs, us] @ Pn[2, :3] + Pn[2, 3]
    good = lam > 0
    vs, us, lam = vs[good], us[good], lam[good]
    dv, du = np.nonzero(domain)
    uc, vc = 0.5 * (du.min() + du.max()), 0.5 * (dv.min() + dv.max())
    scale = max(0.5 * (du.max() - du.min()), 0.5 * (dv.max() - dv.min()), 1.0)
    us_n, vs_n = (us - uc) / scale, (vs - vc) / scale
    # highest degree the data support: enough points and a well-conditioned fit
    # (a leaf seen edge-on covers a sliver of pixels that fixes no curvature across it)
    deg = int(max(1, min(degree, int(np.floor((np.sqrt(8 * max(len(lam), 1) + 1) - 3) / 2)))))
    while deg > 1:
        s = np.linalg.svd(_poly_terms(us_n, vs_n, deg), compute_uv=False)
        if s[-1] > 1e-4 * s[0]:
            break
        deg -= 1
    V = _poly_terms(us_n, vs_n, deg)
    w_data = 1.0 / lam
    # residuals below half a pixel size in depth are never outliers
    f = np.sqrt(abs(np.linalg.det(Pn[:, :3])))
    floor = 0.5 / (f * lam)
    keep = np.ones(len(w_data), bool)
    coef = None
    for _ in range(max(1, iterations)):
        coef, *_ = np.linalg.lstsq(V[keep], w_data[keep], rcond=None)
        res = w_data - V @ coef
        sd = 1.4826 * np.median(np.abs(res[keep]))
        new = np.abs(res) <= np.maximum(3.5 * sd, floor)
        if np.array_equal(new, keep) or new.sum() < V.shape[1]:
            break
        keep = new
    x, y = (du - uc) / scale, (dv - vc) / scale
    w = _poly_terms(x, y, deg) @ coef
    tx, ty = _poly_terms_du(x, y, deg)
    w_u, w_v = (tx @ coef) / scale, (ty @ coef) / scale
    rays = np.stack([du, dv, np.ones_like(du)], axis=1).astype(np.float64) @ Minv.T
    shape = domain.shape + (3,)
    X = np.full(shape, np.nan)
    Xu = np.full(shape, np.nan)
    Xv = np.full(shape, np.nan)
    # keep the model where its depth stays near the data's depths
    lam_in = lam[keep]
    lo, hi = lam_in.min(), lam_in.max()
    pad = 0.5 * (hi - lo) + 0.02 * hi
    with np.errstate(divide="ignore"):
        ok = (w > 0) & (1.0 / w >= lo - pad) & (1.0 / w <= hi + pad)
    X[dv[ok], du[ok]] = C + rays[ok] / w[ok, None]
    Xu[dv[ok], du[ok]] = Minv[:, 0] / w[ok, None] - rays[ok] * (w_u[ok] / w[ok] ** 2)[:, None]
    Xv[dv[ok], du[ok]] = Minv[:, 1] / w[ok, None] - rays[ok] * (w_v[ok] / w[ok] ** 2)[:, None]
    dom = np.zeros(domain.shape, bool)
    dom[dv[ok], du[ok]] = True
    inliers = np.zeros(domain.shape, bool)
    inliers[vs[keep], us[keep]] = True
    return GridSurface(origin=(0, 0), X=X, X_u=Xu, X_v=Xv, domain=dom), inliers


def shift_projection(P, v0: int, u0: int) -> np.ndarray:
    """The camera ``P`` seen from a crop whose top-left pixel is ``(u0, v0)``."""
    T = np.array([[1.0, 0.0, -u0], [0.0, 1.0, -v0], [0.0, 0.0, 1.0]])
    return T @ np.asarray(P, np.float64)


#: Roughness (in pixel sizes) below which a cloud counts as exact (synthetic).
EXACT_ROUGHNESS = 0.02


def roughness(organized: np.ndarray, valid: np.ndarray, *, sigma: float = 1.5, skip_jumps: bool = False) -> float:
    """Small-scale scatter of a surface, in pixel sizes.

    Robust standard deviation of the points' distances (along the local
    normal) from a local-linear fit at ``sigma`` pixels, divided by the pixel
    size (square root of the median pixel footprint). About 0 for exact
    (rendered) surfaces, 0.1 or more for stereo reconstructions. With
    ``skip_jumps`` the pixels whose fit reaches across a depth jump (within
    ``2 sigma`` pixels of a valid 4-neighbour pair more than :data:`JUMP_SPACINGS`
    median neighbour spacings apart: a thin stem before its soil, the background
    a mask took at a leaf's edge) are left out when others remain (at least 16):
    the scatter of the surfaces, not of the steps between them.
    """
    X, Xu, Xv = local_linear_fit(organized, valid, valid, sigma=sigma)
    n = np.cross(Xu, Xv)
    foot = np.linalg.norm(n, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        res = np.einsum("hwk,hwk->hw", organized - X, n / foot[..., None])
    ok = valid & np.isfinite(res) & np.isfinite(foot) & (foot > 0)
    if ok.sum() < 8:
        return float("inf")
    if skip_jumps:
        away = ok & ~_near_jumps(organized, valid, int(np.ceil(2.0 * sigma)))
        if away.sum() >= 16:
            ok = away
    pix = float(np.sqrt(np.median(foot[ok])))
    return float(1.4826 * np.median(np.abs(res[ok])) / pix)


#: A step between 4-neighbours longer than this many median neighbour spacings is a depth jump.
JUMP_SPACINGS = 4.0


def _near_jumps(organized: np.ndarray, valid: np.ndarray, reach: int) -> np.ndarray:
    """(H, W) bool: pixels within ``reach`` pixels of a depth jump between valid 4-neighbours."""
    pts = np.where(valid[..., None], organized, np.nan)
    steps = [np.linalg.norm(pts[:, 1:] - pts[:, :-1], axis=-1), np.linalg.norm(pts[1:] - pts[:-1], axis=-1)]
    finite = np.concatenate([s[np.isfinite(s)] for s in steps])
    jump = np.zeros(valid.shape, bool)
    if not len(finite):
        return jump
    limit = JUMP_SPACINGS * float(np.median(finite))
    with np.errstate(invalid="ignore"):
        across, down = steps[0] > limit, steps[1] > limit
    jump[:, 1:] |= across
    jump[:, :-1] |= across
    jump[1:] |= down
    jump[:-1] |= down
    k = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    return cv2.dilate(jump.astype(np.uint8), k).astype(bool)
