"""Stereo rectification: calibrated (Fusiello 2000) and projective (Hartley 1999).

Both produce two 3x3 homographies that map *ideal* (undistorted) pixels of the
original images to pixels of the rectified images, in which corresponding
points share a row: a left pixel ``(u, v)`` with disparity ``d`` matches the
right pixel ``(u - d, v)``. Lens distortion, when the rig has it, is removed by
the same resampling maps (:class:`StereoRectifier`).
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from canopy_stereo.errors import MatchingError, RigError
from canopy_stereo.geometry.camera import compose_projection, decompose_projection, validate_projection
from canopy_stereo.geometry.distortion import distort_pixels
from canopy_stereo.geometry.triangulation import apply_homography


@dataclass(frozen=True)
class Rectification:
    """Result of a rectification.

    Attributes:
        H_left, H_right: (3, 3) homographies, ideal original pixel -> rectified pixel.
        size: ``(width, height)`` of the rectified images (pixels).
        method: ``"fusiello"`` or ``"hartley"``.
        K_rect_left, K_rect_right: (3, 3) intrinsics of the rectified cameras
            (Fusiello only; one focal length and, but for a pair that was rectified
            already, one principal point).
        R_rect: (3, 3) world-to-rectified-camera rotation shared by both cameras.
        P_rect_left, P_rect_right: (3, 4) world -> rectified pixel (Fusiello only).
        baseline: distance between the camera centres (world units; Fusiello only).
        doffs: ``cx_left - cx_right`` of the rectified cameras (pixels): the
            disparity of a point at infinity (0 for :func:`fusiello_rectify`, but for a
            pair that was rectified already).
        disparity_range: suggested ``(disp_min, disp_max)`` search range in pixels
            (Hartley: from the matches; Fusiello: None, see :func:`default_disparity_range`).
        F: fundamental matrix used (Hartley), ``x_right^T F x_left = 0``.
        n_inliers: matches consistent with ``F`` (Hartley).
    """

    H_left: np.ndarray
    H_right: np.ndarray
    size: tuple[int, int]
    method: str
    K_rect_left: np.ndarray | None = None
    K_rect_right: np.ndarray | None = None
    R_rect: np.ndarray | None = None
    P_rect_left: np.ndarray | None = None
    P_rect_right: np.ndarray | None = None
    baseline: float | None = None
    doffs: float = 0.0
    disparity_range: tuple[int, int] | None = None
    F: np.ndarray | None = None
    n_inliers: int | None = None
    extra: dict = field(default_factory=dict)

    @cached_property
    def H_left_inv(self) -> np.ndarray:
        """Rectified left pixel -> original ideal left pixel."""
        return np.linalg.inv(self.H_left)

    @cached_property
    def H_right_inv(self) -> np.ndarray:
        """Rectified right pixel -> original ideal right pixel."""
        return np.linalg.inv(self.H_right)

    @property
    def focal_length(self) -> float | None:
        """Rectified focal length ``fx`` in pixels (Fusiello only)."""
        return None if self.K_rect_left is None else float(self.K_rect_left[0, 0])


def fusiello_rectify(P_left, P_right, image_size) -> Rectification:
    """Calibrated rectification of Fusiello, Trucco & Verri (2000).

    The new cameras keep the old centres ``C1``, ``C2`` and share one
    orientation: x along the baseline ``C2 - C1``, y orthogonal to x and the
    old left optical axis, z = x * y. They share the focal length (mean of the
    old ones, square pixels) and the whole principal point, as OpenCV's
    ``stereoRectify`` with ``CALIB_ZERO_DISPARITY`` and as every ROS stereo
    calibration: a point at infinity has disparity 0 (``doffs = 0``), so
    ``Z = f B / d`` and image_geometry's Q matrix built from the two rectified
    ``CameraInfo`` messages gives the same depth.

    The principal point keeps the images in view: the left (reference) image
    keeps the point that centres it, so its rectified image, the grid of the
    disparity, depth, mask and cloud, is the same as with per-camera centring,
    and the right camera takes it too. For converging or parallel cameras (the
    right camera's centring point lies left of the left's, ``cx_l >= cx_r``) no
    match is lost by this: what leaves the right image at its far side could never
    be matched by a left pixel. If the right camera's point lies further right
    (diverging principal points) both take the mean, so the two images share
    the loss of view; except for a pair that is already rectified (one
    orientation, the baseline along its x axis, the same ``fx``, ``fy``, ``cy``
    and no skew: Middlebury's pairs, whose ``calib.txt`` gives ``doffs``): it
    keeps its images and both principal points (identity homographies,
    ``doffs = cx_left - cx_right``, negative), as image_geometry reads such a
    ``CameraInfo`` pair, so nothing of either image is cut or resampled.

    Args:
        P_left, P_right: (3, 4) world-frame projection matrices.
        image_size: ``(width, height)`` of the original images; the rectified
            images have the same size.
    """
    P1 = validate_projection(P_left, "P_left")
    P2 = validate_projection(P_right, "P_right")
    w, h = (int(v) for v in image_size)
    cam1, cam2 = decompose_projection(P1), decompose_projection(P2)
    baseline_vec = cam2.C - cam1.C
    B = float(np.linalg.norm(baseline_vec))
    if B <= 0 or not np.isfinite(B):
        raise RigError("the two cameras have the same centre: no baseline to rectify")
    x_axis = baseline_vec / B
    y_axis = np.cross(cam1.R[2], x_axis)
    ny = np.linalg.norm(y_axis)
    if ny < 1e-6:
        raise RigError("the baseline is parallel to the left optical axis: cannot rectify")
    y_axis /= ny
    z_axis = np.cross(x_axis, y_axis)
    R = np.vstack([x_axis, y_axis, z_axis])
    f = float(np.mean([cam1.K[0, 0], cam1.K[1, 1], cam2.K[0, 0], cam2.K[1, 1]]))
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0, 1.0])
    cx, cy = [], []
    for cam in (cam1, cam2):
        ray = R @ cam.R.T @ np.linalg.solve(cam.K, centre)
        if ray[2] <= 0:
            raise RigError("a camera looks away from the rectified viewing direction")
        cx.append(centre[0] - f * ray[0] / ray[2])
        cy.append(centre[1] - f * ray[1] / ray[2])
    if cx[0] < cx[1] and _already_rectified(cam1, cam2, x_axis):
        return _kept_pair(cam1, cam2, B, (w, h), (float(cx[0]), float(cx[1])))
    cx_common = float(cx[0]) if cx[0] >= cx[1] else float(np.mean(cx))
    cy_common = float(np.mean(cy))
    K_new = np.array([[f, 0, cx_common], [0, f, cy_common], [0, 0, 1.0]])
    H1 = K_new @ R @ cam1.R.T @ np.linalg.inv(cam1.K)
    H2 = K_new @ R @ cam2.R.T @ np.linalg.inv(cam2.K)
    return Rectification(
        H_left=H1 / H1[2, 2], H_right=H2 / H2[2, 2], size=(w, h), method="fusiello",
        K_rect_left=K_new, K_rect_right=K_new.copy(), R_rect=R,
        P_rect_left=compose_projection(K_new, R, cam1.C), P_rect_right=compose_projection(K_new, R, cam2.C),
        baseline=B, doffs=0.0, extra={"centring_cx": (float(cx[0]), float(cx[1]))})


def _already_rectified(cam1, cam2, x_axis, *, tol: float = 1e-9) -> bool:
    """Whether two decomposed cameras form a rectified pair already: one orientation, the
    baseline along its x axis, equal ``fx``, ``fy``, ``cy`` (within ``tol`` relative) and no
    skew; only ``cx`` may differ."""
    K1, K2 = cam1.K, cam2.K
    f = max(abs(K1[0, 0]), 1.0)
    return bool(np.allclose(cam1.R, cam2.R, atol=tol) and np.allclose(x_axis, cam1.R[0], atol=1e-6)
                and abs(K1[0, 1]) <= tol * f and abs(K2[0, 1]) <= tol * f
                and all(abs(K1[i, j] - K2[i, j]) <= tol * f for i, j in ((0, 0), (1, 1), (1, 2))))


def _kept_pair(cam1, cam2, baseline: float, size, centring_cx) -> Rectification:
    """The :class:`Rectification` of a pair that is rectified already: identity homographies,
    each camera its own ``K`` (``doffs = cx_left - cx_right``)."""
    K1, K2 = cam1.K / cam1.K[2, 2], cam2.K / cam2.K[2, 2]
    eye = np.eye(3)
    return Rectification(
        H_left=eye, H_right=eye.copy(), size=size, method="fusiello", K_rect_left=K1, K_rect_right=K2,
        R_rect=cam1.R, P_rect_left=compose_projection(K1, cam1.R, cam1.C),
        P_rect_right=compose_projection(K2, cam1.R, cam2.C), baseline=baseline,
        doffs=float(K1[0, 2] - K2[0, 2]), extra={"centring_cx": centring_cx, "already_rectified": True})


def default_disparity_range(rect: Rectification, near_depth: float | None = None,
                            *, far_depth: float | None = None) -> tuple[int, int]:
    """Disparity search range (pixels) for depths in ``[near_depth, far_depth]``.

    Fusiello: :func:`metric_disparity_range` of its focal length, baseline and ``doffs``;
    depths in world units, default near depth 8 baselines (about 240 mm for the
    paper's 29.6 mm baseline) and far depth infinity. Hartley: the range suggested
    by the matches.
    """
    if rect.method != "fusiello":
        if rect.disparity_range is None:
            return 0, 128
        return rect.disparity_range
    assert rect.focal_length is not None and rect.baseline is not None  # (Fusiello sets both)
    return metric_disparity_range(rect.focal_length, rect.baseline, doffs=rect.doffs,
                                  near_depth=near_depth, far_depth=far_depth)


def metric_disparity_range(f: float, baseline: float, *, doffs: float = 0.0, near_depth: float | None = None,
                           far_depth: float | None = None) -> tuple[int, int]:
    """``(disp_min, disp_max)`` (pixels) of a rectified pair for depths in
    ``[near_depth, far_depth]``: ``d = f B / Z + doffs``, one pixel of margin each side.

    Args:
        f: rectified focal length (pixels); baseline: camera distance (any unit);
        doffs: ``cx_left - cx_right`` (0 for this package's rectification);
        near_depth, far_depth: in the baseline's unit (default 8 baselines and infinity).

    The one default for the CLI pipeline and ``disparity_node`` (which knows ``f``
    and the baseline from the CameraInfo pair).
    """
    near = near_depth if near_depth else 8.0 * baseline
    dmax = f * baseline / near + doffs
    dmin = doffs + (f * baseline / far_depth if far_depth else 0.0)
    return max(0, int(np.floor(dmin)) - 1), int(np.ceil(dmax)) + 1


# --------------------------------------------------------------------------- Hartley


def _cross_matrix(e: np.ndarray) -> np.ndarray:
    return np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])


def hartley_rectify(x_left, x_right, image_size, *, F=None, threshold_px: float = 1.0) -> Rectification:
    """Projective rectification from point matches (Hartley 1999; H&Z sec. 11.12).

    1. ``F`` by RANSAC from the matches (unless given; see
       :func:`canopy_stereo.features.estimate_fundamental`); right epipole ``e'``.
    2. ``H' = G R T`` sends ``e'`` to the point at infinity ``(1, 0, 0)``.
    3. ``H = H_A H' M`` with ``M = [e']_x F + e' (1,1,1)^T`` and the affine
       ``H_A`` minimising ``sum (H x_i - H' x'_i)_u^2`` over the inliers.
    4. A common similarity keeps rows aligned, undoes mirroring and centres the
       left image; the right image gets its own horizontal shift so matched
       disparities start a margin above zero.

    Args:
        x_left, x_right: (N, 2) matched ideal (undistorted) pixels, N >= 8.
        image_size: ``(width, height)`` of the original images.
    """
    w, h = (int(v) for v in image_size)
    x1 = np.asarray(x_left, np.float64).reshape(-1, 2)
    x2 = np.asarray(x_right, np.float64).reshape(-1, 2)
    if F is None:
        from canopy_stereo.geometry.fundamental import estimate_fundamental

        F, inl = estimate_fundamental(x1, x2, method="ransac", threshold_px=threshold_px)
    else:
        F = np.asarray(F, np.float64)
        inl = np.ones(len(x1), bool)
    x1, x2 = x1[inl], x2[inl]
    if len(x1) < 8:
        raise MatchingError(f"only {len(x1)} matches agree with F: too few to rectify")
    U, _, _ = np.linalg.svd(F)
    e2 = U[:, 2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    T = np.array([[1, 0, -centre[0]], [0, 1, -centre[1]], [0, 0, 1.0]])
    e2t = T @ e2
    if abs(e2t[2]) < 1e-12 * np.linalg.norm(e2t[:2]):  # epipole already at infinity
        ang = np.arctan2(e2t[1], e2t[0])
        Rz = np.array([[np.cos(ang), np.sin(ang), 0], [-np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])
        G = np.eye(3)
    else:
        ex, ey = e2t[0] / e2t[2], e2t[1] / e2t[2]
        ang = np.arctan2(ey, ex)
        Rz = np.array([[np.cos(ang), np.sin(ang), 0], [-np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])
        fdist = np.hypot(ex, ey)
        G = np.array([[1, 0, 0], [0, 1, 0], [-1.0 / fdist, 0, 1]])
    H2 = G @ Rz @ T
    M = _cross_matrix(e2) @ F + np.outer(e2, np.ones(3))
    H0 = H2 @ M
    p1 = apply_homography(H0, x1)
    p2 = apply_homography(H2, x2)
    A = np.column_stack([p1, np.ones(len(p1))])
    abc, *_ = np.linalg.lstsq(A, p2[:, 0], rcond=None)
    HA = np.array([[abc[0], abc[1], abc[2]], [0, 1, 0], [0, 0, 1.0]])
    H1 = HA @ H0
    H1, H2 = _normalise_rectifying_pair(H1, H2, x1, x2, w, h)
    p1 = apply_homography(H1, x1)
    p2 = apply_homography(H2, x2)
    d = p1[:, 0] - p2[:, 0]
    lo, hi = np.percentile(d, [1, 99])
    margin = max(8.0, 0.2 * (hi - lo))
    shift = margin - lo
    S = np.array([[1, 0, -shift], [0, 1, 0], [0, 0, 1.0]])
    H2 = S @ H2
    drange = (0, int(np.ceil(hi + shift + margin)))
    return Rectification(H_left=H1 / H1[2, 2], H_right=H2 / H2[2, 2], size=(w, h), method="hartley",
                         disparity_range=drange, F=F, n_inliers=int(len(x1)))


def _jacobian(H, p):
    x, y = p
    den = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    nu = H[0, 0] * x + H[0, 1] * y + H[0, 2]
    nv = H[1, 0] * x + H[1, 1] * y + H[1, 2]
    J = np.array([[H[0, 0] * den - nu * H[2, 0], H[0, 1] * den - nu * H[2, 1]],
                  [H[1, 0] * den - nv * H[2, 0], H[1, 1] * den - nv * H[2, 1]]]) / den ** 2
    return J


def _normalise_rectifying_pair(H1, H2, x1, x2, w, h):
    """Apply the same row-preserving similarity to both homographies.

    Flips axes that came out reversed, scales so the left image keeps its area
    at its centre, and centres the left image; rows stay aligned because the
    vertical part of the transform is common.
    """
    c = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    J = _jacobian(H1, c)
    sx = 1.0 if J[0, 0] > 0 else -1.0
    sy = 1.0 if J[1, 1] > 0 else -1.0
    flip = np.diag([sx, sy, 1.0])
    H1, H2 = flip @ H1, flip @ H2
    J = _jacobian(H1, c)
    scale = 1.0 / np.sqrt(abs(np.linalg.det(J)))
    Sc = np.diag([scale, scale, 1.0])
    H1, H2 = Sc @ H1, Sc @ H2
    pc = apply_homography(H1, c[None])[0]
    T = np.array([[1, 0, c[0] - pc[0]], [0, 1, c[1] - pc[1]], [0, 0, 1.0]])
    T2 = T.copy()
    return T @ H1, T2 @ H2


# --------------------------------------------------------------------------- resampling


class StereoRectifier:
    """Precomputed resampling maps that undistort and rectify image pairs.

    Build once per rig and rectification, then call :meth:`rectify` per frame
    (one ``cv2.remap`` per image). The maps are fixed point (``cv2.convertMaps`` to
    ``CV_16SC2`` + ``CV_16UC1``: 1/32 pixel, half the memory of float maps and faster to
    apply to colour images; within 0.1 grey level of float maps on average).

    A side whose map is the identity (a camera that delivers rectified images, e.g. a stereo
    camera that rectifies on board, or a pair rectified already: every rectified pixel is its
    own raw pixel) is not resampled: :meth:`rectify_one` returns the image's pixels as they
    are (what the remap gives at integer positions, bit for bit), saving the remap's CPU
    (4-9 ms per 1280x720 colour image).
    """

    def __init__(self, rig, rect: Rectification, interpolation: int = cv2.INTER_LINEAR):
        self.rig = rig
        self.rect = rect
        self.interpolation = interpolation
        self._maps = [
            _rectify_map(rig.P_left, rig.D_left, rect.H_left_inv, rect.size, rig.distortion_model),
            _rectify_map(rig.P_right, rig.D_right, rect.H_right_inv, rect.size, rig.distortion_model),
        ]
        self._coordinates: list[np.ndarray | None] = [None, None]
        #: per side: the map is the identity (see the class docstring)
        self.identity = tuple(interpolation in (cv2.INTER_NEAREST, cv2.INTER_LINEAR) and _is_identity_map(*m)
                              for m in self._maps)

    def rectify(self, left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified ``(left, right)`` images of size ``rect.size`` (same dtype/channels)."""
        return self.rectify_one(left, "left"), self.rectify_one(right, "right")

    def rectify_one(self, image: np.ndarray, side: str, *, copy: bool = True,
                    out: np.ndarray | None = None) -> np.ndarray:
        """Rectify one image; ``side`` is ``"left"`` or ``"right"``. With ``copy`` False, a
        uint8 image of the rectified size on a side whose map is the identity comes back
        itself (not resampled, not copied: the caller must not write to it). ``out``: an array
        of the result's shape and dtype to write it into (e.g. a message's buffer), returned."""
        i = 0 if side == "left" else 1
        m1, m2 = self._maps[i]
        if self.identity[i] and image.dtype == np.uint8 and image.shape[:2] == m2.shape:
            if out is not None:
                np.copyto(out, image)
                return out
            return np.array(image, copy=True) if copy else image
        if out is not None:
            return cv2.remap(image, m1, m2, self.interpolation, dst=out, borderMode=cv2.BORDER_CONSTANT)
        return cv2.remap(image, m1, m2, self.interpolation, borderMode=cv2.BORDER_CONSTANT)

    def coordinates(self, side: str) -> np.ndarray:
        """float32 (H, W, 2) of the rectified image's size: column and row in the raw
        ``side`` image (pixels) that each rectified pixel samples -- the fixed-point map's
        exact positions, for composing another warp into the rectification (the skew shift,
        :meth:`~canopy_stereo.skew.SkewShift.apply`). Built on first use, read-only."""
        i = 0 if side == "left" else 1
        coords = self._coordinates[i]
        if coords is None:
            m1, m2 = self._maps[i]
            coords = cv2.convertMaps(m1, m2, cv2.CV_32FC2)[0]
            coords.flags.writeable = False
            self._coordinates[i] = coords
        return coords


#: Rectifiers kept by :func:`cached_rectifier` (each holds about 2.5 MB of maps per megapixel).
RECTIFIER_CACHE_SIZE = 4
_rectifier_cache: OrderedDict[bytes, StereoRectifier] = OrderedDict()
_rectifier_lock = threading.Lock()


def _rectifier_key(rig, rect: Rectification, interpolation: int) -> bytes:
    parts = [np.asarray(a, np.float64).tobytes() for a in
             (rig.P_left, rig.P_right, rig.D_left, rig.D_right, rect.H_left, rect.H_right)]
    parts.append(np.asarray(list(rect.size) + [interpolation], np.int64).tobytes())
    parts.append(str(rig.distortion_model).encode())
    return hashlib.sha1(b"".join(parts)).digest()


def cached_rectifier(rig, rect: Rectification, *, interpolation: int = cv2.INTER_LINEAR) -> StereoRectifier:
    """A :class:`StereoRectifier` for ``rig`` and ``rect``, reused while the same camera
    matrices, distortion, homographies and size come back (the maps take 25-40 ms to
    build for 640 x 480, as long as matching the pair). Thread-safe; keeps the
    :data:`RECTIFIER_CACHE_SIZE` most recently used."""
    key = _rectifier_key(rig, rect, interpolation)
    with _rectifier_lock:
        hit = _rectifier_cache.get(key)
        if hit is not None:
            _rectifier_cache.move_to_end(key)
            return hit
    rectifier = StereoRectifier(rig, rect, interpolation)
    with _rectifier_lock:
        _rectifier_cache[key] = rectifier
        while len(_rectifier_cache) > RECTIFIER_CACHE_SIZE:
            _rectifier_cache.popitem(last=False)
    return rectifier


def _rectify_map(P, D, H_inv, size, model=None):
    w, h = size
    vv, uu = np.mgrid[0:h, 0:w]
    p = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    q = distort_pixels(P, D, apply_homography(H_inv, p), model=model)
    mx = q[:, 0].reshape(h, w).astype(np.float32)
    my = q[:, 1].reshape(h, w).astype(np.float32)
    return cv2.convertMaps(mx, my, cv2.CV_16SC2)


def _is_identity_map(map_xy: np.ndarray, map_frac: np.ndarray) -> bool:
    """Whether fixed-point maps (``CV_16SC2`` + ``CV_16UC1``) send every pixel to itself."""
    h, w = map_frac.shape
    if map_frac.any():
        return False
    return bool((map_xy[..., 0] == np.arange(w, dtype=np.int16)).all()
                and (map_xy[..., 1] == np.arange(h, dtype=np.int16)[:, None]).all())


def rectify_pair(left, right, rig, rect: Rectification):
    """Undistort and rectify one pair (maps from :func:`cached_rectifier`)."""
    return cached_rectifier(rig, rect).rectify(left, right)
