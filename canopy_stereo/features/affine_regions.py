"""Harris-affine and Hessian-affine regions (Mikolajczyk & Schmid, IJCV 2004).

1. **Scale-adapted points**: on integration scales ``sigma_I = sigma_0 * xi^n``,
   the Harris measure ``det(mu) - alpha trace(mu)^2`` of the second-moment matrix
   ``mu = sigma_D^2 G(sigma_I) * [Lx^2, LxLy; LxLy, Ly^2]`` (``sigma_D = s sigma_I``)
   or the Hessian determinant ``sigma^4 (Lxx Lyy - Lxy^2)`` is maximised over 3x3
   pixel neighbourhoods.
2. **Laplacian scale selection** (Harris-Laplace / Hessian-Laplace): a point is
   kept on a scale where ``sigma^2 |Lxx + Lyy|`` peaks over the neighbouring scales.
3. **Affine shape adaptation**: the image around the point is resampled through
   an affine map ``U`` so that the region becomes a circle; ``U`` is updated with
   ``mu^(-1/2)`` of the normalised patch (normalised so its largest eigenvalue is
   1; derivatives are taken in the normalised frame) and the point is re-localised on the response maximum, until
   ``mu`` is
   isotropic (eigenvalue ratio >= ``isotropy``); regions that become too elongated
   are dropped. The integration scale stays the one selected in step 2 (the
   original also re-selects it each iteration).
4. **Descriptor**: the normalised patch is rotated to its dominant gradient
   orientation and described by SIFT (OpenCV ``SIFT.compute`` on a mosaic of the
   patches).
"""
from __future__ import annotations

import time

import cv2
import numpy as np
from scipy.ndimage import gaussian_filter

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.descriptor_matching import match_descriptors
from canopy_stereo.features.detectors import Features, make_detector
from canopy_stereo.features.result import MatchResult
from canopy_stereo.features.sparse import verify_matches

#: Patch geometry of the normalised frame: integration scale (patch pixels) and
#: half-size of the adaptation patch.
_SIGMA_N = 2.5
_ADAPT_HALF = 10
#: Differentiation / integration scale ratio.
_S_DIFF = 0.7
#: Descriptor tile: half-size, and the patch radius (pixels) that ``3 sigma_I`` maps to.
_TILE_HALF = 36
_REGION_RADIUS = 20.0


def _gaussian(img, sigma):
    return cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=sigma)


def _derivatives(img):
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
    return gx, gy


def _local_maxima(resp: np.ndarray, threshold: float, border: int) -> np.ndarray:
    """(K, 2) int (u, v) of strict-ish 3x3 local maxima above ``threshold``."""
    dil = cv2.dilate(resp, np.ones((3, 3), np.uint8))
    peak = (resp >= dil) & (resp > threshold)
    peak[:border, :] = False
    peak[-border:, :] = False
    peak[:, :border] = False
    peak[:, -border:] = False
    v, u = np.nonzero(peak)
    return np.column_stack([u, v])


def scale_adapted_points(gray: np.ndarray, kind: str = "harris", *, sigma0: float = 1.4,
                         xi: float = 1.4, n_scales: int = 10, s_diff: float = 0.7,
                         alpha: float = 0.06, threshold: float | None = None,
                         max_points: int = 1500):
    """Harris-Laplace or Hessian-Laplace points.

    Args:
        gray: uint8 (H, W) image.
        kind: ``"harris"`` or ``"hessian"``.
        sigma0, xi, n_scales: integration scales ``sigma0 * xi^n``, n < n_scales.
        s_diff: differentiation scale factor ``sigma_D = s_diff * sigma_I`` (Harris).
        alpha: Harris constant.
        threshold: response threshold (image scaled to [0, 1]); default 2e-7
            (Harris) / 1e-4 (Hessian).
        max_points: keep the strongest this many.

    Returns:
        ``(points (K, 2) float64 pixels, sigma_I (K,) pixels, response (K,))``.
    """
    if kind not in ("harris", "hessian"):
        raise CanopyStereoError(f"unknown affine detector {kind!r}")
    if threshold is None:
        threshold = 2e-7 if kind == "harris" else 1e-4
    img = gray.astype(np.float32) / 255.0
    sigmas = [sigma0 * xi ** n for n in range(n_scales)]
    # scale-normalised Laplacian on every level (plus one below and above for the peak test)
    lap_sigmas = [sigma0 / xi] + sigmas + [sigma0 * xi ** n_scales]
    lap = []
    for s in lap_sigmas:
        g = _gaussian(img, s)
        lap.append(np.abs(cv2.Laplacian(g, cv2.CV_32F, ksize=1)) * s * s)
    pts, scl, rsp = [], [], []
    h, w = img.shape
    for n, s in enumerate(sigmas):
        if kind == "harris":
            sd = s_diff * s
            gx, gy = _derivatives(_gaussian(img, sd))
            k = sd * sd
            a = _gaussian(gx * gx, s) * k
            b = _gaussian(gx * gy, s) * k
            c = _gaussian(gy * gy, s) * k
            resp = a * c - b * b - alpha * (a + c) ** 2
        else:
            g = _gaussian(img, s)
            gxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=1)
            gyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=1)
            gxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=1, scale=0.25)
            resp = (gxx * gyy - gxy * gxy) * s ** 4
        border = int(np.ceil(3 * s)) + 1
        if 2 * border >= min(h, w):
            break
        cand = _local_maxima(resp, threshold, border)
        if len(cand) == 0:
            continue
        u, v = cand[:, 0], cand[:, 1]
        l0, l1, l2 = lap[n][v, u], lap[n + 1][v, u], lap[n + 2][v, u]
        keep = (l1 > l0) & (l1 > l2)
        pts.append(cand[keep].astype(np.float64))
        scl.append(np.full(int(keep.sum()), s))
        rsp.append(resp[v[keep], u[keep]].astype(np.float64))
    if not pts:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    pts, scl, rsp = np.vstack(pts), np.concatenate(scl), np.concatenate(rsp)
    order = np.argsort(-rsp, kind="stable")[:max_points]
    return pts[order], scl[order], rsp[order]


def _sample_patch(img, centre, M, half):
    """Patch (2 half + 1)^2 with patch pixel p -> image pixel centre + M (p - half)."""
    A = np.hstack([M, (np.asarray(centre) - M @ np.array([half, half], float))[:, None]])
    size = 2 * half + 1
    return cv2.warpAffine(img, A, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def _shifted_weights(half, sigma):
    """(9, P, P) Gaussian windows centred on the 3x3 pixels around the patch centre."""
    r = np.arange(-half, half + 1, dtype=np.float64)
    out = []
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            g = np.exp(-((r[None, :] - di) ** 2 + (r[:, None] - dj) ** 2) / (2 * sigma * sigma))
            out.append(g / g.sum())
    return np.array(out)


def affine_adapt(gray: np.ndarray, points: np.ndarray, sigmas: np.ndarray, *, kind: str = "harris",
                 max_iter: int = 10, isotropy: float = 0.95, max_elongation: float = 6.0):
    """Affine shape adaptation of scale-adapted points (all points iterated together).

    Returns ``(points (K, 2), shapes (K, 2, 2), sigmas (K,))`` of the converged
    regions: the region is ``{x : |inv(shape) (x - point)| <= 3 sigma}`` with the
    shape's largest singular value 1.
    """
    n = len(points)
    if n == 0:
        return np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros(0)
    img = gray.astype(np.float32) / 255.0
    h, w = img.shape
    half = _ADAPT_HALF
    w_shift = _shifted_weights(half, _SIGMA_N)              # (9, P, P); index 4 = centre
    blurred = {}
    X = np.asarray(points, np.float64).copy()
    S = np.asarray(sigmas, np.float64)
    U = np.tile(np.eye(2), (n, 1, 1))
    step = S / _SIGMA_N                                     # image pixels per patch pixel
    state = np.zeros(n, np.int8)                            # 0 active, 1 converged, -1 dropped
    offsets = np.array([[di, dj] for dj in (-1, 0, 1) for di in (-1, 0, 1)], np.float64)
    for _ in range(max_iter):
        act = np.nonzero(state == 0)[0]
        if len(act) == 0:
            break
        patches = np.empty((len(act), 2 * half + 1, 2 * half + 1), np.float32)
        for k, i in enumerate(act):
            key = round(float(S[i]), 6)
            if key not in blurred:
                blurred[key] = _gaussian(img, 0.5 * step[i])  # anti-aliasing only
            patches[k] = _sample_patch(blurred[key], X[i], step[i] * U[i], half)
        # differentiation scale applied in the normalised frame (elliptical in the image)
        patches = gaussian_filter(patches, (0, _S_DIFF * _SIGMA_N, _S_DIFF * _SIGMA_N),
                                  mode="nearest")
        gy, gx = np.gradient(patches, axis=(1, 2))
        gxx, gxy, gyy = gx * gx, gx * gy, gy * gy
        mu = np.empty((len(act), 2, 2))
        mu[:, 0, 0] = np.einsum("ij,nij->n", w_shift[4], gxx)
        mu[:, 0, 1] = mu[:, 1, 0] = np.einsum("ij,nij->n", w_shift[4], gxy)
        mu[:, 1, 1] = np.einsum("ij,nij->n", w_shift[4], gyy)
        # re-localise on the response maximum among the 3x3 centre pixels
        c = half
        if kind == "harris":
            a = np.einsum("kij,nij->nk", w_shift, gxx)
            b = np.einsum("kij,nij->nk", w_shift, gxy)
            d = np.einsum("kij,nij->nk", w_shift, gyy)
            resp = a * d - b * b - 0.06 * (a + d) ** 2
        else:
            P = patches.astype(np.float64)
            resp = np.empty((len(act), 9))
            for k, (di, dj) in enumerate(offsets.astype(int)):
                y, x = c + dj, c + di
                lxx = P[:, y, x + 1] - 2 * P[:, y, x] + P[:, y, x - 1]
                lyy = P[:, y + 1, x] - 2 * P[:, y, x] + P[:, y - 1, x]
                lxy = 0.25 * (P[:, y + 1, x + 1] - P[:, y + 1, x - 1] - P[:, y - 1, x + 1]
                              + P[:, y - 1, x - 1])
                resp[:, k] = lxx * lyy - lxy * lxy
        best = np.argmax(resp, axis=1)
        X[act] += step[act, None] * np.einsum("nij,nj->ni", U[act], offsets[best])
        inside = (X[act, 0] >= 0) & (X[act, 0] < w) & (X[act, 1] >= 0) & (X[act, 1] < h)
        vals, vecs = np.linalg.eigh(mu)
        degenerate = vals[:, 0] <= 1e-12
        state[act[~inside | degenerate]] = -1
        iso = ~degenerate & (vals[:, 0] >= isotropy * vals[:, 1]) & inside
        state[act[iso]] = 1
        upd = inside & ~degenerate & ~iso
        if not upd.any():
            continue
        vu, Vu = vals[upd], vecs[upd]
        inv_sqrt = np.einsum("nij,nj,nkj->nik", Vu, 1.0 / np.sqrt(vu), Vu)
        Unew = U[act[upd]] @ inv_sqrt
        sv = np.linalg.svd(Unew, compute_uv=False)
        Unew /= sv[:, :1, None]
        U[act[upd]] = Unew
        state[act[upd][sv[:, 0] / sv[:, 1] > max_elongation]] = -1
    ok = state == 1
    return X[ok], U[ok], S[ok]


def _dominant_orientation(patch: np.ndarray, radius: float) -> float:
    """Angle (radians) of the peak of the 36-bin, Gaussian-weighted gradient histogram."""
    gx, gy = _derivatives(patch)
    half = patch.shape[0] // 2
    r = np.arange(-half, half + 1, dtype=np.float32)
    wgt = np.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * (0.5 * radius) ** 2))
    mag = np.hypot(gx, gy) * wgt
    ang = np.arctan2(gy, gx)
    hist, edges = np.histogram(ang, bins=36, range=(-np.pi, np.pi), weights=mag)
    hist = np.convolve(np.r_[hist[-1], hist, hist[0]], [0.25, 0.5, 0.25], mode="valid")
    k = int(np.argmax(hist))
    return float(0.5 * (edges[k] + edges[k + 1]))


def describe_regions(gray: np.ndarray, points, shapes, sigmas, *, detector=None) -> np.ndarray:
    """SIFT descriptors (K, 128) float32 of the normalised, orientation-aligned regions."""
    k = len(points)
    if k == 0:
        return np.zeros((0, 128), np.float32)
    det = detector if detector is not None else make_detector("sift")
    img = gray.astype(np.float32)
    size = 2 * _TILE_HALF + 1
    cols = int(np.ceil(np.sqrt(k)))
    rows = int(np.ceil(k / cols))
    mosaic = np.zeros((rows * size, cols * size), np.float32)
    keypoints = []
    blurred = {}
    for i, (p, U, s) in enumerate(zip(points, shapes, sigmas)):
        step = 3.0 * s / _REGION_RADIUS
        key = round(float(step), 3)
        if key not in blurred:
            blurred[key] = _gaussian(img, max(0.5 * step, 0.01)) if step > 1.0 else img
        patch = _sample_patch(blurred[key], p, step * U, _TILE_HALF)
        theta = _dominant_orientation(patch, _REGION_RADIUS)
        c, sn = np.cos(theta), np.sin(theta)
        Rot = np.array([[c, -sn], [sn, c]])
        patch = _sample_patch(blurred[key], p, step * U @ Rot, _TILE_HALF)
        r, q = divmod(i, cols)
        mosaic[r * size:(r + 1) * size, q * size:(q + 1) * size] = patch
        keypoints.append(cv2.KeyPoint(float(q * size + _TILE_HALF), float(r * size + _TILE_HALF),
                                      _REGION_RADIUS / 3.0, 0.0))
    mosaic8 = np.clip(mosaic, 0, 255).astype(np.uint8)
    kps, desc = det.compute(mosaic8, keypoints)
    if desc is None or len(kps) != k:
        # OpenCV dropped keypoints (it should not for interior tiles); map back by position
        full = np.zeros((k, 128), np.float32)
        if desc is not None:
            for kp, d in zip(kps, desc):
                q = int(round((kp.pt[0] - _TILE_HALF) / size))
                r = int(round((kp.pt[1] - _TILE_HALF) / size))
                full[r * cols + q] = d
        return full
    return desc.astype(np.float32)


def detect_affine_regions(gray: np.ndarray, kind: str = "harris", *, detector=None, **params) -> Features:
    """Harris-affine / Hessian-affine regions of a grey image with SIFT descriptors."""
    pts, sig, _ = scale_adapted_points(gray, kind, **params)
    pts, shapes, sig = affine_adapt(gray, pts, sig, kind=kind)
    desc = describe_regions(gray, pts, shapes, sig, detector=detector)
    return Features(pts, desc, False, 6.0 * sig)


def _affine_match(kind, left_gray, right_gray, ratio, mutual, f_method, threshold_px, params):
    det = make_detector("sift")
    size = (left_gray.shape[1], left_gray.shape[0])
    t0 = time.perf_counter()
    fl = detect_affine_regions(left_gray, kind, detector=det, **params)
    t1 = time.perf_counter()
    fr = detect_affine_regions(right_gray, kind, detector=det, **params)
    t2 = time.perf_counter()
    il, ir = match_descriptors(fl.descriptors, fr.descriptors, ratio=ratio, mutual=mutual)
    xl, xr = fl.points[il], fr.points[ir]
    F, keep, note = verify_matches(xl, xr, f_method=f_method, threshold_px=threshold_px)
    t3 = time.perf_counter()
    name = f"{kind}-affine"
    if len(fl) == 0 or len(fr) == 0:
        note = f"no {name} regions in the {'left' if len(fl) == 0 else 'right'} image (no texture?)"
    return MatchResult(method=name, x_left=xl[keep], x_right=xr[keep], image_size=size,
                       num_left=len(fl), num_right=len(fr), t_left=t1 - t0, t_right=t2 - t1,
                       t_match=t3 - t2, F=F, note=note, extras={"num_tentative": int(len(il))})


def harris_affine_match(left_gray, right_gray, *, ratio: float = 0.8, mutual: bool = True,
                        f_method: str = "ransac", threshold_px: float = 1.0, **params) -> MatchResult:
    """Harris-affine regions + SIFT descriptors, matched and verified (one study row).

    ``params`` go to :func:`scale_adapted_points` (``sigma0``, ``n_scales``,
    ``threshold``, ``max_points``, ...).
    """
    return _affine_match("harris", left_gray, right_gray, ratio, mutual, f_method, threshold_px, params)


def hessian_affine_match(left_gray, right_gray, *, ratio: float = 0.8, mutual: bool = True,
                         f_method: str = "ransac", threshold_px: float = 1.0, **params) -> MatchResult:
    """Hessian-affine regions + SIFT descriptors, matched and verified (one study row)."""
    return _affine_match("hessian", left_gray, right_gray, ratio, mutual, f_method, threshold_px, params)
