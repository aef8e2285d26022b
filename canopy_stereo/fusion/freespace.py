"""Free-space evidence: does a view see *through* a point that another view reported?

A view with a camera and a depth image says that the space between its
camera and each observed surface is empty. A point ``X`` that projects into
that view at a pixel whose observed depth is clearly greater than ``X``'s own
depth lies on such an empty ray segment: the view saw through it. A point seen
by only one view and seen through by another is an outlier (a mismatch of the
first view's stereo matcher, a floating speck) and fusion drops it.

The depth image is eroded (minimum over a small window, pixels without data
count as depth 0) so a point near a depth edge is never judged against the
background beside the edge, and a missing observation is never evidence.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from canopy_stereo.geometry.camera import normalize_projection, point_depth, project
from canopy_stereo.geometry.transforms import invert_transform


@dataclass
class DepthView:
    """A view's camera in the world frame and what it observed.

    Attributes:
        P: (3, 4) world -> pixels, scaled so ``(P X)[2]`` is the depth (world units).
        depth: (H, W) float32 eroded depth image, 0 where nothing was observed.
    """

    P: np.ndarray
    depth: np.ndarray

    @classmethod
    def from_organized(cls, P_rig, organized, pose, *, erode_px: int = 2) -> DepthView:
        """From a rig-frame organized cloud on the left pixel grid of camera ``P_rig``."""
        org = np.asarray(organized, np.float64)
        h, w = org.shape[:2]
        flat = org.reshape(-1, 3)
        ok = np.all(np.isfinite(flat), axis=1)
        depth = np.zeros(h * w, np.float32)
        depth[ok] = point_depth(P_rig, flat[ok])
        depth[depth < 0] = 0
        return cls._make(P_rig, depth.reshape(h, w), pose, erode_px)

    @classmethod
    def from_points(cls, P_rig, points, image_size, pose, *, erode_px: int = 2) -> DepthView:
        """From rig-frame points (N, 3) splatted into camera ``P_rig`` (nearest depth per pixel)."""
        w, h = int(image_size[0]), int(image_size[1])
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        z = point_depth(P_rig, pts)
        uv = np.rint(project(P_rig, pts)).astype(np.int64)
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < w) & (uv[:, 1] < h)
        zbuf = np.full(h * w, np.inf)
        np.minimum.at(zbuf, uv[ok, 1] * w + uv[ok, 0], z[ok])
        zbuf[~np.isfinite(zbuf)] = 0
        return cls._make(P_rig, zbuf.reshape(h, w).astype(np.float32), pose, erode_px)

    @classmethod
    def _make(cls, P_rig, depth, pose, erode_px):
        P_world = normalize_projection(np.asarray(P_rig, np.float64) @ invert_transform(pose))
        if erode_px > 0:
            k = 2 * int(erode_px) + 1
            depth = cv2.erode(depth, np.ones((k, k), np.uint8), borderType=cv2.BORDER_CONSTANT,
                              borderValue=0)
        return cls(P=P_world, depth=depth)

    def seen_through(self, points, margin_abs: float, margin_rel: float) -> np.ndarray:
        """(N,) bool: this view observed a surface clearly behind each world point.

        "Clearly" means deeper by more than ``max(margin_abs, margin_rel * depth)``.
        """
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        h, w = self.depth.shape
        x = pts @ self.P[:, :3].T + self.P[:, 3]
        z = x[:, 2]
        out = np.zeros(len(pts), bool)
        front = z > 0
        u = np.rint(x[front, 0] / z[front]).astype(np.int64)
        v = np.rint(x[front, 1] / z[front]).astype(np.int64)
        inside = (u >= 0) & (v >= 0) & (u < w) & (v < h)
        idx = np.nonzero(front)[0][inside]
        zi = z[idx]
        observed = self.depth[v[inside], u[inside]]
        out[idx] = observed > zi + np.maximum(margin_abs, margin_rel * zi)
        return out
