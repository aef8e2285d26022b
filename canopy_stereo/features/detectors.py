"""OpenCV keypoint detectors/descriptors: SIFT, ORB, AKAZE, KAZE (and SURF where built).

Each detector turns a grey uint8 image into ``Features``: keypoint positions in
pixels ``(u, v)`` and descriptors. AKAZE/KAZE moved out of the main OpenCV
module in OpenCV 5, and SURF is patented (only in opencv-contrib builds with
``OPENCV_ENABLE_NONFREE``); :func:`detector_available` says which exist here.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError


@dataclass
class Features:
    """Keypoints of one image.

    Attributes:
        points: (N, 2) float64 keypoint positions ``(u, v)``, pixels.
        descriptors: (N, D) float32 (or uint8 for binary descriptors).
        binary: True when descriptors compare by Hamming distance.
        scales: (N,) keypoint diameters in pixels (OpenCV ``KeyPoint.size``).
    """

    points: np.ndarray
    descriptors: np.ndarray
    binary: bool
    scales: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def _features_from_cv(keypoints, descriptors, binary: bool, dim: int) -> Features:
    if descriptors is None or len(keypoints) == 0:
        dtype = np.uint8 if binary else np.float32
        return Features(np.zeros((0, 2)), np.zeros((0, dim), dtype), binary, np.zeros(0))
    pts = np.array([kp.pt for kp in keypoints], dtype=np.float64).reshape(-1, 2)
    sizes = np.array([kp.size for kp in keypoints], dtype=np.float64)
    return Features(pts, descriptors, binary, sizes)


def _surf_factory():
    xf = getattr(cv2, "xfeatures2d", None)
    if xf is None or not hasattr(xf, "SURF_create"):
        return None
    try:
        return xf.SURF_create(400)
    except cv2.error:  # contrib without OPENCV_ENABLE_NONFREE
        return None


# name -> (factory(**params) or None when absent, binary descriptors?, descriptor length)
_FACTORIES = {
    "sift": (getattr(cv2, "SIFT_create", None), False, 128),
    "orb": (getattr(cv2, "ORB_create", None), True, 32),
    "akaze": (getattr(cv2, "AKAZE_create", None), True, 61),
    "kaze": (getattr(cv2, "KAZE_create", None), False, 64),
}

_ABSENT_REASON = {
    "akaze": "AKAZE is not in this OpenCV build (OpenCV {v} moved it to opencv-contrib)",
    "kaze": "KAZE is not in this OpenCV build (OpenCV {v} moved it to opencv-contrib)",
    "surf": "SURF is patented and absent from pip OpenCV {v} (needs a contrib build with "
            "OPENCV_ENABLE_NONFREE); no row is faked",
}


def detector_available(name: str) -> tuple[bool, str]:
    """``(available, reason)`` for an OpenCV detector name; reason is "" when available."""
    if name == "surf":
        ok = _surf_factory() is not None
    elif name in _FACTORIES:
        ok = _FACTORIES[name][0] is not None
    else:
        raise CanopyStereoError(f"unknown detector {name!r}")
    return ok, ("" if ok else _ABSENT_REASON.get(name, f"{name} is not available").format(
        v=cv2.__version__))


def make_detector(name: str, **params):
    """The OpenCV ``Feature2D`` for ``name`` (``sift``, ``orb``, ``akaze``, ``kaze``, ``surf``)."""
    ok, reason = detector_available(name)
    if not ok:
        raise CanopyStereoError(reason)
    if name == "surf":
        det = _surf_factory()
        if params.get("hessian_threshold") is not None:
            det.setHessianThreshold(float(params["hessian_threshold"]))
        return det
    factory = _FACTORIES[name][0]
    if name == "orb":
        params.setdefault("nfeatures", 5000)
    try:
        return factory(**params)
    except (cv2.error, TypeError) as exc:
        raise CanopyStereoError(f"bad {name} parameters {params}: {exc}") from None


def detect_and_describe(gray: np.ndarray, name: str, *, detector=None, mask=None, **params) -> Features:
    """Keypoints and descriptors of a grey uint8 image with the OpenCV detector ``name``."""
    det = detector if detector is not None else make_detector(name, **params)
    kps, desc = det.detectAndCompute(gray, mask)
    binary = name in ("orb", "akaze")
    dim = _FACTORIES[name][2] if name in _FACTORIES else 64
    return _features_from_cv(kps, desc, binary, dim)
