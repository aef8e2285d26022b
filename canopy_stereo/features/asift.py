"""ASIFT: affine simulation + SIFT (Morel & Yu, SIAM J. Imaging Sciences 2009).

Each image is viewed under simulated camera-axis tilts ``t`` (``1, sqrt 2, 2, ...``)
and longitudes ``phi`` (``0 <= phi < 180`` deg in steps of ``72 / t`` deg): the image
is rotated by ``phi``, blurred along x with ``sigma = 0.8 sqrt(t^2 - 1)`` and
subsampled along x by ``t``. SIFT keypoints of every simulated view are mapped
back to original pixels and pooled.

Matching pools all views: because one physical point is detected in several
views with nearly equal descriptors, the ratio test compares the nearest
neighbour with the nearest one lying more than ``same_point_px`` away (in
original pixels), the mutual check accepts a back-match within that distance,
and duplicate matches are merged. A robust F then verifies the matches.
"""
from __future__ import annotations

import time

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.features.descriptor_matching import _knn
from canopy_stereo.features.detectors import Features, make_detector
from canopy_stereo.features.result import MatchResult
from canopy_stereo.features.sparse import verify_matches


def simulated_views(max_tilt: float = 4.0, longitude_step_deg: float = 72.0):
    """The ``(tilt, phi_deg)`` pairs of the simulation, ``tilt = sqrt(2)^k <= max_tilt``."""
    if max_tilt < 1.0:
        raise CanopyStereoError(f"max_tilt must be >= 1, got {max_tilt}")
    views = [(1.0, 0.0)]
    k = 1
    while np.sqrt(2.0) ** k <= max_tilt * (1 + 1e-9):
        t = float(np.sqrt(2.0) ** k)
        step = longitude_step_deg / t
        count = int(np.ceil(180.0 / step - 1e-6))          # phi in [0, 180)
        views += [(t, float(step * i)) for i in range(count)]
        k += 1
    return views


def simulate_view(gray: np.ndarray, tilt: float, phi_deg: float):
    """One affine simulation of a grey image.

    Returns ``(view, mask, A)``: the simulated uint8 image, a uint8 mask of its
    valid pixels, and the (2, 3) affine map original pixel -> view pixel.
    """
    h, w = gray.shape
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    img = gray
    mask = np.full((h, w), 255, np.uint8)
    if phi_deg != 0.0:
        phi = np.deg2rad(phi_deg)
        c, s = np.cos(phi), np.sin(phi)
        R = np.array([[c, -s], [s, c]])
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], float) @ R.T
        lo = corners.min(axis=0)
        hi = corners.max(axis=0)
        A = np.hstack([R, -lo[:, None]])
        size = (int(np.ceil(hi[0] - lo[0])) + 1, int(np.ceil(hi[1] - lo[1])) + 1)
        img = cv2.warpAffine(gray, A, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        mask = cv2.warpAffine(mask, A, size, flags=cv2.INTER_NEAREST, borderValue=0)
    if tilt != 1.0:
        sigma = 0.8 * np.sqrt(tilt * tilt - 1.0)
        img = cv2.GaussianBlur(img, (0, 0), sigmaX=sigma, sigmaY=0.01)
        old_w = img.shape[1]
        new_w = max(1, int(round(old_w / tilt)))
        img = cv2.resize(img, (new_w, img.shape[0]), interpolation=cv2.INTER_LINEAR)
        mask = cv2.resize(mask, (new_w, mask.shape[0]), interpolation=cv2.INTER_NEAREST)
        # cv2.resize maps pixel centres: x' = (x + 0.5) * s - 0.5 with s = new_w / old_w
        sx = new_w / float(old_w)
        S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        A = (S @ np.vstack([A, [0.0, 0.0, 1.0]]))[:2]
    # keep keypoints away from the simulated image's border
    mask = cv2.erode(mask, np.ones((5, 5), np.uint8))
    return img, mask, A


def detect_asift(gray: np.ndarray, views=None, *, detector=None) -> Features:
    """Pooled SIFT features of all simulated views, positions in original pixels."""
    det = detector if detector is not None else make_detector("sift")
    views = views if views is not None else simulated_views()
    pts, descs, sizes = [], [], []
    for tilt, phi in views:
        img, mask, A = simulate_view(gray, tilt, phi)
        kps, desc = det.detectAndCompute(img, mask)
        if desc is None or not kps:
            continue
        p = np.array([kp.pt for kp in kps], np.float64)
        Ainv = cv2.invertAffineTransform(A)
        pts.append(p @ Ainv[:, :2].T + Ainv[:, 2])
        descs.append(desc)
        sizes.append(np.array([kp.size for kp in kps]))
    if not pts:
        return Features(np.zeros((0, 2)), np.zeros((0, 128), np.float32), False, np.zeros(0))
    return Features(np.vstack(pts), np.vstack(descs).astype(np.float32), False, np.concatenate(sizes))


def match_pooled(feat_left: Features, feat_right: Features, *, ratio: float = 0.8,
                 mutual: bool = True, same_point_px: float = 3.0, k: int = 8):
    """Location-aware ratio test and mutual check for pooled multi-view features.

    Returns ``(idx_left, idx_right)`` with duplicates (same left and right pixel
    within 1 px) merged.
    """
    if len(feat_left) == 0 or len(feat_right) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dist, idx = _knn(feat_left.descriptors, feat_right.descriptors, k, binary=False)
    pr = feat_right.points
    first = idx[:, 0]
    valid = first >= 0
    # second neighbour: the nearest one that is a different point of the right image
    far = np.zeros_like(valid)
    d2 = np.full(len(idx), np.inf)
    for j in range(1, idx.shape[1]):
        cand = idx[:, j]
        ok = (cand >= 0) & ~far
        sep = np.full(len(idx), False)
        sep[ok] = np.hypot(*(pr[cand[ok]] - pr[first[ok]]).T) > same_point_px
        newly = ok & sep
        d2[newly] = dist[newly, j]
        far |= newly
    keep = valid & (dist[:, 0] < ratio * d2)
    il = np.nonzero(keep)[0]
    ir = first[il]
    if mutual and len(il):
        _, back = _knn(feat_right.descriptors, feat_left.descriptors, 1, binary=False)
        bl = back[ir, 0]
        close = np.hypot(*(feat_left.points[bl] - feat_left.points[il]).T) <= same_point_px
        il, ir = il[close], ir[close]
    if len(il):
        key = np.column_stack([np.rint(feat_left.points[il]), np.rint(pr[ir])]).astype(np.int64)
        _, first_of = np.unique(key, axis=0, return_index=True)
        first_of.sort()
        il, ir = il[first_of], ir[first_of]
    return il.astype(np.int64), ir.astype(np.int64)


def asift_match(left_gray: np.ndarray, right_gray: np.ndarray, *, ratio: float = 0.8,
                mutual: bool = True, f_method: str = "ransac", threshold_px: float = 1.0,
                max_tilt: float = 4.0, longitude_step_deg: float = 72.0,
                same_point_px: float = 3.0, sift_params: dict | None = None) -> MatchResult:
    """ASIFT matches of a grey pair (one row of the study).

    Args:
        left_gray, right_gray: uint8 (H, W) images.
        ratio, mutual, f_method, threshold_px: matching and verification.
        max_tilt: largest simulated tilt (Morel & Yu use up to ``4 sqrt 2``).
        longitude_step_deg: ``b`` in the longitude step ``b / t``.
        same_point_px: features closer than this (original pixels) count as one point.
        sift_params: arguments of ``cv2.SIFT_create``.
    """
    det = make_detector("sift", **(sift_params or {}))
    views = simulated_views(max_tilt, longitude_step_deg)
    size = (left_gray.shape[1], left_gray.shape[0])
    t0 = time.perf_counter()
    fl = detect_asift(left_gray, views, detector=det)
    t1 = time.perf_counter()
    fr = detect_asift(right_gray, views, detector=det)
    t2 = time.perf_counter()
    il, ir = match_pooled(fl, fr, ratio=ratio, mutual=mutual, same_point_px=same_point_px)
    xl, xr = fl.points[il], fr.points[ir]
    F, keep, note = verify_matches(xl, xr, f_method=f_method, threshold_px=threshold_px)
    t3 = time.perf_counter()
    if len(fl) == 0 or len(fr) == 0:
        note = f"no asift features in the {'left' if len(fl) == 0 else 'right'} image (no texture?)"
    return MatchResult(method="asift", x_left=xl[keep], x_right=xr[keep], image_size=size,
                       num_left=len(fl), num_right=len(fr), t_left=t1 - t0, t_right=t2 - t1,
                       t_match=t3 - t2, F=F, note=note,
                       extras={"num_tentative": int(len(il)), "num_views": len(views)})
