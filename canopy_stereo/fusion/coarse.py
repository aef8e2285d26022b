"""Coarse alignment of two views from feature matches lifted to 3-D.

Each view has a left image and its organized cloud (the 3-D point of every
left pixel, NaN where none). SIFT keypoints are detected where the view has
3-D points, matched between the two left images (nearest neighbour + ratio
test + mutual check, :mod:`canopy_stereo.features`), and every match is lifted
to a pair of 3-D points. A rigid transform is then found by RANSAC over
minimal 3-match samples (Kabsch fit of each sample, all hypotheses scored at
once), and refitted to all its inliers. The two images are of different
viewpoints, so the epipolar verification of a stereo pair does not apply; the
3-D rigidity test replaces it.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.fusion.errors import RegistrationError
from canopy_stereo.geometry.transforms import rigid_fit, rigid_fit_batch, transform_points
from canopy_stereo.io.images import to_gray


@dataclass
class FeatureAlignment:
    """One candidate of :func:`align_keypoints`.

    Attributes:
        transform: (4, 4) source rig frame -> target rig frame.
        matches: descriptor matches lifted to 3-D in both views.
        inliers: matches consistent with ``transform`` within ``threshold``.
        rms: RMS 3-D distance of the inliers after the fit, world units.
        threshold: inlier distance used, world units.
    """

    transform: np.ndarray
    matches: int
    inliers: int
    rms: float
    threshold: float


@dataclass
class Keypoints3D:
    """Keypoints of one view with descriptors and 3-D positions (view's rig frame)."""

    pixels: np.ndarray
    descriptors: np.ndarray
    points: np.ndarray


def lift_pixels(organized, pixels, *, max_spread: float | None = None) -> np.ndarray:
    """3-D points (N, 3) of sub-pixel keypoints on an organized cloud (NaN where none).

    The point is the organized cloud at the nearest pixel; with ``max_spread``
    the 3x3 neighbourhood must be complete and its points within that distance
    of the centre (keypoints on depth edges are dropped).
    """
    org = np.asarray(organized, np.float64)
    h, w = org.shape[:2]
    uv = np.rint(np.asarray(pixels, np.float64).reshape(-1, 2)).astype(np.int64)
    out = np.full((len(uv), 3), np.nan)
    inside = (uv[:, 0] >= 1) & (uv[:, 1] >= 1) & (uv[:, 0] < w - 1) & (uv[:, 1] < h - 1)
    idx = np.nonzero(inside)[0]
    u, v = uv[idx, 0], uv[idx, 1]
    centre = org[v, u]
    good = np.all(np.isfinite(centre), axis=1)
    if max_spread is not None:
        for dv in (-1, 0, 1):
            for du in (-1, 0, 1):
                nb = org[v + dv, u + du]
                d = np.linalg.norm(nb - centre, axis=1)
                good &= np.isfinite(d) & (d <= max_spread)
    out[idx[good]] = centre[good]
    return out


#: Affine simulations ``(tilt, angle in degrees)`` of :func:`keypoints_3d` (ASIFT-style):
#: the image itself and a tilt of sqrt(2) (a 45 degree turn of the surface) in four directions.
DEFAULT_TILTS = ((1.0, 0.0),) + tuple((float(np.sqrt(2.0)), a) for a in (0.0, 45.0, 90.0, 135.0))


def _simulated_view(gray, mask, tilt: float, angle_deg: float):
    """The image rotated by ``angle_deg`` then compressed along x by ``tilt`` (anti-aliased).

    Returns ``(image, mask, A)`` with ``A`` (2, 3) mapping original pixels to the simulated image.
    """
    h, w = gray.shape
    if tilt == 1.0 and angle_deg == 0.0:
        return gray, mask, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    R = cv2.getRotationMatrix2D(((w - 1) / 2.0, (h - 1) / 2.0), angle_deg, 1.0)
    rot = cv2.warpAffine(gray, R, (w, h), flags=cv2.INTER_LINEAR)
    rmask = cv2.warpAffine(mask, R, (w, h), flags=cv2.INTER_NEAREST)
    if tilt > 1.0:
        rot = cv2.GaussianBlur(rot, (0, 0), sigmaX=0.8 * np.sqrt(tilt * tilt - 1.0), sigmaY=0.01)
    S = np.array([[1.0 / tilt, 0.0], [0.0, 1.0]])
    A = S @ R
    A[0, 2] += 0.5 / tilt - 0.5  # pixel centres: u' + 0.5 = (u + 0.5) / tilt
    size = (max(1, int(round(w / tilt))), h)
    img = cv2.warpAffine(rot, np.hstack([S, [[0.5 / tilt - 0.5], [0.0]]]), size, flags=cv2.INTER_LINEAR)
    m = cv2.warpAffine(rmask, np.hstack([S, [[0.5 / tilt - 0.5], [0.0]]]), size, flags=cv2.INTER_NEAREST)
    return img, m, A


def keypoints_3d(image, organized, *, max_spread: float | None = None, tilts=DEFAULT_TILTS,
                 max_features: int = 0) -> Keypoints3D:
    """SIFT keypoints of a view's left image that have a 3-D point.

    Views of a plant from directions 45 degrees apart see each leaf foreshortened
    differently, which plain SIFT tolerates poorly; as in ASIFT (Morel & Yu),
    keypoints are also detected on affine simulations of the image (``tilts``:
    ``(tilt, angle)`` pairs) and mapped back to the original pixels.

    Args:
        image: left image (grey or BGR uint8).
        organized: (H, W, 3) rig-frame points of its pixels (NaN where none).
        max_spread: drop keypoints on depth edges (see :func:`lift_pixels`).
        tilts: affine simulations; ``((1, 0),)`` is plain SIFT.
        max_features: SIFT's feature limit per simulated image (0 = none).
    """
    from canopy_stereo.features.detectors import detect_and_describe, make_detector

    gray = to_gray(np.asarray(image), "left image")
    org = np.asarray(organized, np.float64)
    if org.shape[:2] != gray.shape[:2]:
        raise CanopyStereoError(f"organized cloud is {org.shape[1]}x{org.shape[0]} but the image is "
                                f"{gray.shape[1]}x{gray.shape[0]}")
    valid = np.all(np.isfinite(org), axis=2).astype(np.uint8) * 255
    valid = cv2.erode(valid, np.ones((5, 5), np.uint8))
    detector = make_detector("sift", nfeatures=int(max_features))
    pixels, descriptors = [np.zeros((0, 2))], [np.zeros((0, 128), np.float32)]
    for tilt, angle in tilts:
        img, mask, A = _simulated_view(gray, valid, float(tilt), float(angle))
        feats = detect_and_describe(img, "sift", detector=detector, mask=mask)
        if len(feats) == 0:
            continue
        Ai = cv2.invertAffineTransform(A)
        pixels.append(feats.points @ Ai[:, :2].T + Ai[:, 2])
        descriptors.append(feats.descriptors.astype(np.float32))
    px, desc = np.concatenate(pixels), np.concatenate(descriptors)
    pts3 = lift_pixels(org, px, max_spread=max_spread)
    keep = np.all(np.isfinite(pts3), axis=1)
    return Keypoints3D(pixels=px[keep], descriptors=desc[keep], points=pts3[keep])


def _best_rigid(src, dst, threshold, iterations, rng):
    """Best 3-point RANSAC hypothesis: ``(T, inlier mask)`` or None when no sample is rigid."""
    n = len(src)
    samples = np.stack([rng.choice(n, 3, replace=False) for _ in range(iterations)])
    s, d = src[samples], dst[samples]                      # (M, 3, 3)
    # a rigid motion preserves the sample's side lengths; skip hypotheses that do not
    sides_s = np.linalg.norm(s - np.roll(s, 1, axis=1), axis=2)
    sides_d = np.linalg.norm(d - np.roll(d, 1, axis=1), axis=2)
    rigid = np.all(np.abs(sides_s - sides_d) < 2 * threshold, axis=1) & np.all(sides_s > 4 * threshold, axis=1)
    if not np.any(rigid):
        return None
    Ts = rigid_fit_batch(s[rigid], d[rigid])
    counts = np.zeros(len(Ts), np.int64)
    for a in range(0, len(Ts), 128):  # score hypotheses in blocks to bound memory
        blk = Ts[a:a + 128]
        moved = np.einsum("mij,nj->mni", blk[:, :3, :3], src) + blk[:, None, :3, 3]
        counts[a:a + 128] = (np.linalg.norm(moved - dst[None], axis=2) < threshold).sum(axis=1)
    best = int(np.argmax(counts))
    inl = np.linalg.norm(transform_points(Ts[best], src) - dst, axis=1) < threshold
    if inl.sum() < 3:
        return None
    T = rigid_fit(src[inl], dst[inl])
    for _ in range(3):  # refit to the inliers of the refined transform
        inl_new = np.linalg.norm(transform_points(T, src) - dst, axis=1) < threshold
        if inl_new.sum() < 3 or np.array_equal(inl_new, inl):
            break
        inl = inl_new
        T = rigid_fit(src[inl], dst[inl])
    return T, inl


def ransac_rigid(source, target, threshold: float, *, iterations: int = 2000, seed: int = 0,
                 min_inliers: int = 8, hypotheses: int = 1):
    """Robust rigid transforms ``target ~ T source`` from putative 3-D matches.

    Sequential RANSAC: the best 3-point hypothesis is refitted to its inliers,
    which are then set aside and the search repeated, up to ``hypotheses``
    times. Several hypotheses matter when part of the scene moves differently
    from the rest, e.g. a pot that is turned on a turntable but looks the same
    at every angle (its matches agree on "no motion"), so the hypothesis with
    the most matches is not always the plant's.

    Args:
        source, target: (N, 3) matched points.
        threshold: inlier distance ``|T s - t|``, world units.
        iterations: number of 3-point samples per hypothesis.
        min_inliers: fewest inliers of an accepted hypothesis.
        hypotheses: how many distinct hypotheses to return at most.

    Returns:
        List of ``(T (4, 4), inlier mask (N,))``, most inliers first; raises
        :class:`RegistrationError` when not even one has ``min_inliers``.
    """
    src = np.asarray(source, np.float64).reshape(-1, 3)
    dst = np.asarray(target, np.float64).reshape(-1, 3)
    n = len(src)
    if n < max(3, min_inliers):
        raise RegistrationError(f"only {n} feature matches with 3-D points (need {max(3, min_inliers)})")
    rng = np.random.default_rng(seed)
    out = []
    remaining = np.arange(n)
    for _ in range(max(1, int(hypotheses))):
        if len(remaining) < max(3, min_inliers):
            break
        found = _best_rigid(src[remaining], dst[remaining], threshold, iterations, rng)
        if found is None:
            break
        T, inl_sub = found
        if inl_sub.sum() < min_inliers:
            break
        inl = np.linalg.norm(transform_points(T, src) - dst, axis=1) < threshold
        out.append((T, inl))
        remaining = remaining[~inl_sub]
    if not out:
        best = 0 if found is None else int(found[1].sum())
        raise RegistrationError(f"only {best} of {n} feature matches agree on one rigid motion "
                                f"within {threshold:g} (need {min_inliers})")
    return out


def align_keypoints(source: Keypoints3D, target: Keypoints3D, threshold: float, *, ratio: float = 0.8,
                    min_inliers: int = 10, iterations: int = 2000, seed: int = 0,
                    hypotheses: int = 3) -> list[FeatureAlignment]:
    """Candidate rigid motions source -> target from two views' :class:`Keypoints3D`.

    Descriptors are matched (nearest neighbour, ratio test, mutual check) and the
    lifted 3-D pairs go through :func:`ransac_rigid`.

    Returns:
        :class:`FeatureAlignment` list, most inliers first (a caller verifies
        them, e.g. by ICP overlap).

    Raises:
        RegistrationError: too few matches or no consistent rigid motion (the
            views do not overlap or share no texture).
    """
    from canopy_stereo.features.descriptor_matching import match_descriptors

    if len(source.points) < 3 or len(target.points) < 3:
        raise RegistrationError(f"too few keypoints with 3-D points ({len(source.points)} and "
                                f"{len(target.points)})")
    il, ir = match_descriptors(source.descriptors, target.descriptors, ratio=ratio, mutual=True)
    src, dst = source.points[il], target.points[ir]
    out = []
    for T, inl in ransac_rigid(src, dst, threshold, iterations=iterations, seed=seed,
                               min_inliers=min_inliers, hypotheses=hypotheses):
        resid = np.linalg.norm(transform_points(T, src[inl]) - dst[inl], axis=1)
        out.append(FeatureAlignment(transform=T, matches=int(len(il)), inliers=int(inl.sum()),
                                    rms=float(np.sqrt(np.mean(resid ** 2))), threshold=float(threshold)))
    return out


def align_by_features(source_image, source_organized, target_image, target_organized,
                      threshold: float, **kwargs) -> list[FeatureAlignment]:
    """Candidate rigid motions source view -> target view from their left images and
    organized clouds ((H, W, 3) rig-frame points of the left pixels).

    ``threshold``: RANSAC inlier distance, world units (a few times the depth
    noise); other keyword arguments go to :func:`align_keypoints`.
    """
    return align_keypoints(keypoints_3d(source_image, source_organized, max_spread=threshold),
                           keypoints_3d(target_image, target_organized, max_spread=threshold),
                           threshold, **kwargs)
