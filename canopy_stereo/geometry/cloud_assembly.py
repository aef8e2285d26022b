"""A point cloud node's arithmetic: ``Q`` of a DisparityImage, and coloured clouds from a
rectified disparity.

Two paths, as ``point_cloud_node`` takes them (it only converts messages and calls these):

* a calibrated (REP 104) left rectified camera: ``Q`` from the ``DisparityImage``'s ``f``,
  ``t`` and the left rectified ``P`` (:func:`disparity_image_reprojection`), then
  :func:`~canopy_stereo.geometry.frames.reproject_disparity_records`;
* any rectification (Hartley's projective one too): back-mapping to the raw pixels and DLT
  with the world-frame ``P`` (:func:`cloud_from_disparity`, the reference path).

Units: pixels in, the world frame times ``scale`` out (metres on the wire).
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import ImageError, RigError
from canopy_stereo.geometry.frames import reprojection_matrix
from canopy_stereo.geometry.triangulation import triangulate_disparity_points


def disparity_image_reprojection(f: float, t: float, P_left) -> np.ndarray:
    """image_geometry's ``Q`` (4x4) for the disparities of a ``stereo_msgs/DisparityImage``
    (focal length ``f`` in pixels, baseline ``t`` in metres; the disparities are already
    reduced by ``cx_left - cx_right``, so ``Q[3, 3] = 0``) and the left rectified ``P`` (3x4,
    REP 104: ``fx``, ``fy``, ``cx``, ``cy`` are read from it): :func:`reprojection_matrix` of
    that camera and one ``t`` to its right with the same principal point. Points come out in
    the left rectified optical frame, metres."""
    Pl = np.asarray(P_left, np.float64)
    if not (f > 0 and t > 0 and Pl[0, 0] > 0 and Pl[1, 1] > 0):
        raise RigError("the disparity or camera_info has no focal length/baseline")
    Pr = Pl.copy()
    Pr[0, 3] = -Pl[0, 0] * float(t)
    return reprojection_matrix(Pl, Pr)


def window_slices(valid_window, shape) -> tuple[slice, slice]:
    """``(rows, cols)`` slices of a ``DisparityImage``'s ``valid_window`` ``(x, y, width,
    height)`` (pixels; outside it no disparity is valid) clipped to ``shape`` ``(H, W)``;
    the whole image when the window is empty or unset (width or height 0)."""
    h, w = (int(v) for v in shape)
    x, y, ww, hh = (int(v) for v in valid_window)
    if ww <= 0 or hh <= 0:
        return slice(0, h), slice(0, w)
    x0, y0 = min(max(x, 0), w), min(max(y, 0), h)
    return slice(y0, min(max(y + hh, y0), h)), slice(x0, min(max(x + ww, x0), w))


def offset_reprojection(Q, x0: int, y0: int) -> np.ndarray:
    """``Q`` (4x4) for the pixels of a crop starting at column ``x0``, row ``y0``: crop pixel
    ``(u, v)`` reprojects as full-image pixel ``(u + x0, v + y0)``."""
    Qc = np.array(Q, np.float64)
    Qc[:, 3] += Qc[:, 0] * float(x0) + Qc[:, 1] * float(y0)
    return Qc


def check_cloud_inputs(disp: np.ndarray, colours: np.ndarray, *, mask=None, size=None) -> None:
    """:class:`~canopy_stereo.errors.ImageError` unless the colour image, the optional mask
    and the rectified ``size`` ``(w, h)`` (if given) have the disparity's grid."""
    h, w = disp.shape
    if size is not None and (w, h) != tuple(size):
        raise ImageError(f"disparity is {w}x{h} but the rectified images are {size[0]}x{size[1]}")
    if colours.shape[:2] != disp.shape:
        raise ImageError(f"colour image is {colours.shape[1]}x{colours.shape[0]}, disparity {w}x{h}")
    if mask is not None and mask.shape != disp.shape:
        raise ImageError(f"mask is {mask.shape[1]}x{mask.shape[0]}, disparity {w}x{h}")


def cloud_from_disparity(disp: np.ndarray, colours: np.ndarray, rect, P_left, P_right, *,
                         scale: float = 1.0, mask=None, organized: bool = True):
    """Points and colours of the valid rectified left pixels, by back-mapping + DLT with the
    world-frame ``P`` (any rectification).

    Args:
        disp: float32 (Hr, Wr) rectified disparity ``u_left - u_right``, invalid < 0.
        colours: (Hr, Wr) or (Hr, Wr, C) per-pixel colours of the rectified left image
            (e.g. PointCloud2's packed ``rgb``).
        rect: the :class:`~canopy_stereo.geometry.rectification.Rectification`.
        P_left, P_right: (3, 4) world-frame projection matrices.
        scale: factor on the world coordinates (the rig's metres per unit for metres).
        mask: optional (Hr, Wr) mask, 0 = drop the pixel.
        organized: the rectified grid (NaN where no point) rather than only the valid points.

    Returns ``(points, colours)``: float32 world points times ``scale``, (Hr, Wr, 3) and the
    colours as given when ``organized``, else (N, 3) and the N colours of those pixels.
    """
    check_cloud_inputs(disp, colours, mask=mask, size=rect.size)
    h, w = disp.shape
    points, index = triangulate_disparity_points(disp, rect, P_left, P_right, scale=scale, mask=mask,
                                                 organized=organized)
    flat = colours.reshape(h * w, *colours.shape[2:])
    if organized:
        return points.reshape(h, w, 3), colours
    return points, flat[index]
