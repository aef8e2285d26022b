"""Exact point correspondences of a rendered pair (ground truth for feature matching)."""
from __future__ import annotations

import numpy as np

from canopy_stereo.geometry.camera import project
from canopy_stereo.geometry.distortion import distort_pixels


def true_right_pixels(sim, *, visible_tol: float | None = None) -> np.ndarray:
    """The right pixel that sees the same world point as each left pixel.

    Args:
        sim: a :class:`~canopy_stereo.sim.render.SimResult` (world frame and unit of its rig).
        visible_tol: a left pixel's point counts as visible in the right image when the
            point the right image sees at the (rounded) projection is within this
            distance of it, world units; default 2 mm expressed in the rig's unit
            (occluded points have no correspondence).

    Returns:
        (H, W, 2) float64 ``(u', v')`` right pixel of each left pixel centre
        (unrounded projection, through the rig's lens distortion), NaN where the left pixel sees nothing, the point
        leaves the right image or is hidden from the right camera.
    """
    from canopy_stereo.io.rig import unit_to_metres

    if visible_tol is None:
        unit = getattr(sim.rig, "world_unit", "mm") or "mm"
        visible_tol = 0.002 / unit_to_metres(unit)
    h, w = sim.xyz_left.shape[:2]
    X = sim.xyz_left.reshape(-1, 3)
    ok = np.all(np.isfinite(X), axis=1)
    xr = np.full((len(X), 2), np.nan)
    xr[ok] = project(sim.rig.P_right, X[ok])
    D = getattr(sim.rig, "D_right", None)
    if D is not None and np.any(np.asarray(D) != 0):
        xr[ok] = distort_pixels(sim.rig.P_right, D, xr[ok],     # the pixel the image shows
                                model=getattr(sim.rig, "distortion_model", None))
    u = np.rint(xr[:, 0])
    v = np.rint(xr[:, 1])
    inside = ok & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    idx = np.nonzero(inside)[0]
    seen = np.zeros(len(X), bool)
    Xr = sim.xyz_right[v[idx].astype(int), u[idx].astype(int)]
    seen[idx] = np.linalg.norm(Xr - X[idx], axis=1) < visible_tol
    xr[~seen] = np.nan
    return xr.reshape(h, w, 2)


__all__ = ["true_right_pixels"]
