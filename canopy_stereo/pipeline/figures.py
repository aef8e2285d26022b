"""Pictures of the pipeline's results drawn with OpenCV only (no plotting library).

* :func:`epipolar_figure`: the paper's Figure 11, epipolar lines before and after
  a rectification (lines computed from F, not assumed horizontal);
* :func:`render_cloud`: a coloured point cloud seen from a virtual camera turned
  about the cloud (z-buffered splats), the paper's "reconstructed 3D result";
* :func:`panel_row`: images side by side with captions.

Images are uint8 BGR; pixels ``u`` right, ``v`` down, top-left pixel centre (0, 0).
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import decompose_projection
from canopy_stereo.geometry.triangulation import apply_homography
from canopy_stereo.io.images import to_bgr

#: Colours of the three feature points / epipolar lines (BGR).
LINE_COLOURS = ((0, 0, 255), (0, 200, 0), (255, 64, 0))


def _line_ends(line, size):
    """End points (two (u, v)) of the line ``a u + b v + c = 0`` clipped to the image, or None."""
    a, b, c = (float(x) for x in line)
    w, h = size
    pts = []
    if abs(b) > 1e-12:
        for u in (0.0, w - 1.0):
            v = -(a * u + c) / b
            if -0.5 <= v <= h - 0.5:
                pts.append((u, v))
    if abs(a) > 1e-12:
        for v in (0.0, h - 1.0):
            u = -(b * v + c) / a
            if -0.5 <= u <= w - 0.5:
                pts.append((u, v))
    if len(pts) < 2:
        return None
    pts = sorted(set(pts))
    return pts[0], pts[-1]


def line_angle_deg(line) -> float:
    """Angle of the line ``a u + b v + c = 0`` to the image rows, degrees in (-90, 90]."""
    a, b, _ = (float(x) for x in line)
    ang = np.degrees(np.arctan2(-a, b))          # direction (b, -a)
    if ang <= -90:
        ang += 180
    elif ang > 90:
        ang -= 180
    return float(ang)


def label(img, text, *, org=(6, 6), scale=0.55):
    """Draw ``text`` in black on a white box whose top-left corner is ``org`` (in place)."""
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x, y = org
    cv2.rectangle(img, (x, y), (x + tw + 8, y + th + base + 6), (255, 255, 255), -1)
    cv2.putText(img, text, (x + 4, y + th + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1,
                cv2.LINE_AA)
    return img


def epipolar_figure(left, right, rectified_left, rectified_right, F, H_left, H_right,
                    points_left) -> tuple[np.ndarray, dict]:
    """The paper's Figure 11: three left points and their epipolar lines, before and after.

    Args:
        left, right: original images (grey or BGR uint8).
        rectified_left, rectified_right: the rectified images.
        F: (3, 3) fundamental matrix of the original pair, ``x_r^T F x_l = 0``.
        H_left, H_right: (3, 3) rectifying homographies (original -> rectified pixels).
        points_left: (K, 2) left pixels to draw (the paper draws three).

    Returns:
        ``(figure, numbers)``: a 2x2 BGR mosaic (a: original left with the points,
        b: original right with their epipolar lines, c: rectified left with the
        mapped points, d: rectified right with the lines of the rectified pair's
        fundamental matrix ``H_r^-T F H_l^-1``) and a dict with the lines'
        angles to the image rows (degrees) before (``angles_before``) and after
        (``angles_after``).
    """
    F = np.asarray(F, np.float64)
    H_left = np.asarray(H_left, np.float64)
    H_right = np.asarray(H_right, np.float64)
    pts = np.asarray(points_left, np.float64).reshape(-1, 2)
    a, b = to_bgr(left, "left").copy(), to_bgr(right, "right").copy()
    c, d = to_bgr(rectified_left, "rectified left").copy(), to_bgr(rectified_right, "rectified right").copy()
    F_rect = np.linalg.inv(H_right).T @ F @ np.linalg.inv(H_left)
    pts_rect = apply_homography(H_left, pts)
    before, after = [], []
    for k, (p, q) in enumerate(zip(pts, pts_rect)):
        col = LINE_COLOURS[k % len(LINE_COLOURS)]
        cv2.circle(a, (int(round(p[0])), int(round(p[1]))), 6, col, 2, cv2.LINE_AA)
        cv2.circle(c, (int(round(q[0])), int(round(q[1]))), 6, col, 2, cv2.LINE_AA)
        line = F @ np.array([p[0], p[1], 1.0])
        line_r = F_rect @ np.array([q[0], q[1], 1.0])
        before.append(line_angle_deg(line))
        after.append(line_angle_deg(line_r))
        for img, ln in ((b, line), (d, line_r)):
            ends = _line_ends(ln, (img.shape[1], img.shape[0]))
            if ends is not None:
                (u0, v0), (u1, v1) = ends
                cv2.line(img, (int(round(u0)), int(round(v0))), (int(round(u1)), int(round(v1))),
                         col, 2, cv2.LINE_AA)
    label(a, "a) original left, three points")
    label(b, "b) original right, their epipolar lines")
    label(c, "c) rectified left")
    label(d, "d) rectified right, epipolar lines")
    top = panel_row([a, b])
    bottom = panel_row([c, d])
    width = max(top.shape[1], bottom.shape[1])
    top = _pad_to(top, width)
    bottom = _pad_to(bottom, width)
    fig = np.vstack([top, np.full((6, width, 3), 255, np.uint8), bottom])
    return fig, {"angles_before": before, "angles_after": after}


def _pad_to(img, width):
    if img.shape[1] == width:
        return img
    pad = np.full((img.shape[0], width - img.shape[1], 3), 255, np.uint8)
    return np.hstack([img, pad])


def panel_row(images, captions=None, *, gap: int = 6) -> np.ndarray:
    """Images (grey or BGR uint8) side by side at the height of the tallest, with
    optional captions drawn in their top-left corners."""
    imgs = [to_bgr(np.asarray(im), "panel").copy() for im in images]
    if not imgs:
        raise CanopyStereoError("no image to put in a row")
    h = max(im.shape[0] for im in imgs)
    out = []
    for k, im in enumerate(imgs):
        if im.shape[0] != h:
            scale = h / im.shape[0]
            im = cv2.resize(im, (int(round(im.shape[1] * scale)), h), interpolation=cv2.INTER_AREA)
        if captions is not None and captions[k]:
            label(im, captions[k])
        out.append(im)
        if k < len(imgs) - 1:
            out.append(np.full((h, gap, 3), 255, np.uint8))
    return np.hstack(out)


def _rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    y, p = np.radians(yaw_deg), np.radians(pitch_deg)
    Ry = np.array([[np.cos(y), 0, np.sin(y)], [0, 1, 0], [-np.sin(y), 0, np.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    return Rx @ Ry


def render_cloud(points, colors, P_view, *, yaw_deg: float = 30.0, pitch_deg: float = 20.0,
                 size=(640, 480), splat_px: int = 2, background=(255, 255, 255),
                 fill: float = 0.85) -> np.ndarray:
    """Draw a coloured point cloud as seen by a virtual camera turned about the cloud.

    The virtual camera starts at the camera of ``P_view`` (its centre and axes, from
    the 3x4 projection matrix) and orbits the cloud's median point by ``yaw_deg``
    about the camera's vertical axis and ``pitch_deg`` about its horizontal axis
    (positive pitch looks down from above); its focal length makes the cloud fill
    ``fill`` of the picture. Points are splatted as ``splat_px`` squares, nearest last.

    Args:
        points: (N, 3) world points (any unit).
        colors: (N, 3) uint8 RGB colours.
        P_view: (3, 4) projection matrix of the camera the cloud was seen from.
        size: ``(width, height)`` of the picture.

    Returns:
        (height, width, 3) uint8 BGR picture.
    """
    X = np.asarray(points, np.float64).reshape(-1, 3)
    col = np.asarray(colors, np.uint8).reshape(-1, 3)
    if len(X) != len(col):
        raise CanopyStereoError(f"{len(X)} points but {len(col)} colours")
    w, h = int(size[0]), int(size[1])
    img = np.empty((h, w, 3), np.uint8)
    img[:] = background
    ok = np.all(np.isfinite(X), axis=1)
    X, col = X[ok], col[ok]
    if len(X) == 0:
        return img
    cam = decompose_projection(P_view)
    C, R = cam.C, cam.R
    target = np.median(X, axis=0)
    dist = np.linalg.norm(target - C)
    Rv = _rotation(yaw_deg, pitch_deg) @ R                      # world -> virtual camera axes
    Cv = target - dist * Rv[2]                                  # looking at the target
    Xc = (X - Cv) @ Rv.T
    front = Xc[:, 2] > 1e-9 * dist
    Xc, col = Xc[front], col[front]
    if len(Xc) == 0:
        return img
    xn = Xc[:, :2] / Xc[:, 2:3]
    lo, hi = np.percentile(xn, [1, 99], axis=0)
    span = np.maximum(hi - lo, 1e-9)
    f = fill * min(w / span[0], h / span[1])
    centre = 0.5 * (lo + hi)
    u = f * (xn[:, 0] - centre[0]) + (w - 1) / 2.0
    v = f * (xn[:, 1] - centre[1]) + (h - 1) / 2.0
    order = np.argsort(-Xc[:, 2], kind="stable")               # far first, near drawn last
    u, v, col = u[order], v[order], col[order]
    ui = np.rint(u).astype(np.int64)
    vi = np.rint(v).astype(np.int64)
    bgr = col[:, ::-1]
    for dv in range(splat_px):
        for du in range(splat_px):
            uu, vv = ui + du, vi + dv
            inside = (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
            img[vv[inside], uu[inside]] = bgr[inside]
    return img


__all__ = ["LINE_COLOURS", "epipolar_figure", "label", "line_angle_deg", "panel_row", "render_cloud"]
