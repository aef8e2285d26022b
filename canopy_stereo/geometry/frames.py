"""Coordinate frames of a stereo rig (REP 103 / REP 105) and its cameras' calibration (REP 104).

Pure numpy: what the ROS nodes publish as ``sensor_msgs/CameraInfo`` and ``/tf_static``.

Frames (names follow REP 103: a camera's optical frame is ``<camera>_optical_frame``,
z forward, x right, y down):

* :data:`WORLD_FRAME` ``canopy_world``: the rig's world frame, the metric frame the rig
  file's ``P`` matrices map from (the paper's frame), in metres on the ROS side;
* ``left_camera_optical_frame``, ``right_camera_optical_frame``: the raw cameras;
  both raw ``CameraInfos`` (and images) of a pair carry the *left* one, and both
  rectified ones ``left_camera_rect_optical_frame`` (:func:`stereo_info_frame`):
  image_geometry's ``StereoCameraModel`` asserts one frame for the two infos ("both the
  left and right CameraInfo should be in the left optical frame"); the right camera's
  pose is in the right ``P``'s ``Tx`` and in ``/tf_static``;
* ``left_camera_rect_optical_frame``, ``right_camera_rect_optical_frame``: the rectified
  cameras of the Fusiello rectification (same centres, one shared orientation); the
  rectified images, disparities, depth images and (by parameter) the cloud are here;
* :data:`WORLD_Z_UP_FRAME` ``canopy_world_z_up``: the world turned so that z points up
  and x along the cameras' horizontal viewing direction (REP 103 body axes: x forward,
  y left, z up), so RViz (z up) shows the plant upright.

Mounted on a robot (REP 105), the world frame gets a parent: ``parent -> world`` by the
*mount* (:func:`mount_transform`), and the z-up view becomes a child of the world frame
(a frame has one parent). ``frame_prefix`` (:func:`prefixed_frames`) is prepended to every
frame the rig names, so that two rigs share one tree.

A transform ``T_a_b`` is a 4x4 matrix taking coordinates in frame ``b`` to frame ``a``
(``x_a = T_a_b @ x_b``), which is what a TF message ``header.frame_id = a``,
``child_frame_id = b`` carries. Translations are in metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.camera import decompose_projection
from canopy_stereo.geometry.transforms import invert_transform
from canopy_stereo.geometry.triangulation import kernel_mask

#: The rig's world frame (metres).
WORLD_FRAME = "canopy_world"
#: The z-up view of the world frame for RViz.
WORLD_Z_UP_FRAME = "canopy_world_z_up"
#: Camera names of the raw and rectified cameras.
CAMERA_NAMES = {("raw", "left"): "left_camera", ("raw", "right"): "right_camera",
                ("rect", "left"): "left_camera_rect", ("rect", "right"): "right_camera_rect"}


def optical_frame(camera: str) -> str:
    """REP 103 optical frame of a camera: ``left_camera`` -> ``left_camera_optical_frame``."""
    return camera if camera.endswith("_optical_frame") else f"{camera}_optical_frame"


#: Default frame ids: ("raw" | "rect", "left" | "right") -> optical frame name.
DEFAULT_FRAMES = {key: optical_frame(name) for key, name in CAMERA_NAMES.items()}


def transform_from_pose(R_cam_world, C_world, *, scale: float = 1.0) -> np.ndarray:
    """``T_world_cam`` (4x4): camera coordinates (metres) -> world coordinates (metres).

    Args:
        R_cam_world: (3, 3) world-to-camera rotation (rows = camera axes in world coordinates).
        C_world: (3,) camera centre in world units.
        scale: metres per world unit.
    """
    R = np.asarray(R_cam_world, np.float64)
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = np.asarray(C_world, np.float64).reshape(3) * float(scale)
    return T


def rotation_to_quaternion(R) -> np.ndarray:
    """Unit quaternion ``(x, y, z, w)`` (ROS order, ``w >= 0``) of a 3x3 rotation matrix."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, 0.25 * s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s, (R[2, 1] - R[1, 2]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s, (R[0, 2] - R[2, 0]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s, (R[1, 0] - R[0, 1]) / s]
    quat = np.asarray(q, np.float64)
    quat /= np.linalg.norm(quat)
    return -quat if quat[3] < 0 else quat


def quaternion_to_rotation(q) -> np.ndarray:
    """3x3 rotation matrix of a quaternion ``(x, y, z, w)``."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def z_up_rotation(up_world, forward_world) -> np.ndarray:
    """``R_zup_world`` (3x3): world -> z-up frame with z = ``up_world`` and x = the part of
    ``forward_world`` orthogonal to it (REP 103 body axes: x forward, y left, z up)."""
    up = np.asarray(up_world, np.float64).reshape(3)
    n = np.linalg.norm(up)
    if not np.isfinite(n) or n == 0:
        raise RigError("world_up must be a non-zero 3-vector")
    up = up / n
    fwd = np.asarray(forward_world, np.float64).reshape(3)
    fwd = fwd - (fwd @ up) * up
    nf = np.linalg.norm(fwd)
    if nf < 1e-6:
        raise RigError("world_up is parallel to the cameras' viewing direction: no forward axis")
    x = fwd / nf
    y = np.cross(up, x)
    return np.vstack([x, y, up])


@dataclass(frozen=True)
class CameraCalibration:
    """One camera's ``sensor_msgs/CameraInfo`` matrices (REP 104).

    Attributes:
        width, height: image size (pixels).
        K: (3, 3) intrinsics of the raw image (pixels).
        D: distortion coefficients (OpenCV order), ``distortion_model`` names their model.
        R: (3, 3) rotation from this camera's optical frame to the rectified camera's.
        P: (3, 4) ``[K' | (Tx, 0, 0)]`` of the rectified camera, ``Tx = -fx' B`` (metres)
           for the right camera, 0 for the left.
    """

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray
    R: np.ndarray
    P: np.ndarray
    distortion_model: str = "plumb_bob"


def distortion_model_for(D) -> str:
    """``plumb_bob`` for up to 5 OpenCV coefficients, ``rational_polynomial`` for 8 (REP 104)."""
    n = len(np.asarray(D).ravel())
    return "plumb_bob" if n <= 5 else "rational_polynomial"


#: ``D`` of a raw camera without lens distortion whose ``R`` is not the identity:
#: ``rational_polynomial`` with ``k1 = k4 = 1`` (nothing else). image_geometry treats an
#: all-zero ``D`` as "no distortion" and its ``rectifyImage`` then copies the raw image,
#: ignoring ``R`` and ``P``; with this ``D`` it builds the maps, and OpenCV's radial factor
#: ``(1 + k1 r^2 + ...) / (1 + k4 r^2 + ...)`` is exactly 1 (the same operations above and
#: below the line), so the image is rectified with no distortion applied.
ZERO_DISTORTION_RECTIFIABLE = (1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)


def camera_info_distortion(D, model: str | None, R) -> tuple[np.ndarray, str]:
    """``(D, distortion_model)`` to publish in a raw ``CameraInfo`` (the one decision):
    the lens's own when it has distortion; for none, zeros (``plumb_bob``) when ``R`` is
    the identity, else :data:`ZERO_DISTORTION_RECTIFIABLE` so image_proc rectifies."""
    from canopy_stereo.geometry.distortion import distortion_is_identity

    D = np.asarray(D, np.float64).ravel()
    if not distortion_is_identity(D, model=model):
        return D, model or distortion_model_for(D)
    if np.allclose(np.asarray(R, np.float64), np.eye(3), rtol=0, atol=1e-12):
        return np.zeros(5), "plumb_bob"
    return np.array(ZERO_DISTORTION_RECTIFIABLE), "rational_polynomial"


def stereo_info_frame(names: FrameNames, kind: str) -> str:
    """Frame id of BOTH ``CameraInfos`` (and images) of a pair: the left camera's
    (``kind`` ``"raw"`` or ``"rect"``), as image_geometry's ``StereoCameraModel`` requires."""
    return names.raw_left if kind == "raw" else names.rect_left


def stereo_extrinsics(rig, rect=None) -> dict:
    """World transforms of the rig's cameras: ``{(kind, side): T_world_cam}`` (4x4, metres).

    ``kind`` is ``"raw"`` (the original cameras, from the rig's ``P``) or ``"rect"`` (the
    rectified cameras; only when ``rect`` is a calibrated (Fusiello) rectification).
    """
    m = rig.metres_per_unit
    out = {}
    cams = {"left": decompose_projection(rig.P_left), "right": decompose_projection(rig.P_right)}
    for side, cam in cams.items():
        out[("raw", side)] = transform_from_pose(cam.R, cam.C, scale=m)
        if rect is not None and rect.R_rect is not None:
            out[("rect", side)] = transform_from_pose(rect.R_rect, cam.C, scale=m)
    return out


def world_z_up_transform(rig) -> np.ndarray:
    """``T_zup_world`` (4x4): a pure rotation making z point up.

    "Up" is the rig file's ``world_up`` (3 numbers, world coordinates) when it has one,
    else the left camera's image-up direction (minus its y axis: the camera is assumed
    held with its rows level). x is the left camera's viewing direction made horizontal.
    """
    cam = decompose_projection(rig.P_left)
    up = rig.extra.get("world_up")
    up = -cam.R[1] if up is None or len(up) == 0 else np.asarray(up, np.float64)
    T = np.eye(4)
    T[:3, :3] = z_up_rotation(up, cam.R[2])
    return T


def raw_camera_calibration(rig, side: str, *, rect=None) -> CameraCalibration:
    """REP 104 calibration of the raw ``side`` camera of ``rig``.

    ``K`` and ``D`` are the camera's own (``D`` as :func:`camera_info_distortion` publishes
    it); ``R`` and ``P`` describe the rig's Fusiello
    rectification (``rect``, computed when None), so that image_geometry and image_proc,
    given only this ``CameraInfo``, rectify exactly as :class:`StereoRectifier` does.
    """
    from canopy_stereo.geometry.rectification import fusiello_rectify

    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    if rect is None or rect.R_rect is None:
        rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    P_world = rig.P_left if side == "left" else rig.P_right
    D = rig.D_left if side == "left" else rig.D_right
    cam = decompose_projection(P_world)
    K_rect = rect.K_rect_left if side == "left" else rect.K_rect_right
    P = rectified_projection(K_rect, rect.baseline * rig.metres_per_unit, side)
    w, h = rig.image_size
    R = rect.R_rect @ cam.R.T
    D_info, model = camera_info_distortion(D, getattr(rig, "distortion_model", None), R)
    return CameraCalibration(width=w, height=h, K=cam.K, D=D_info, R=R, P=P, distortion_model=model)


def rectified_projection(K_rect, baseline_m: float, side: str) -> np.ndarray:
    """REP 104 ``P = [K | (Tx, 0, 0)]`` of a rectified camera: ``Tx = 0`` (left) or
    ``-fx * baseline`` in metres (right)."""
    K = np.asarray(K_rect, np.float64)
    P = np.hstack([K, np.zeros((3, 1))])
    if side == "right":
        P[0, 3] = -K[0, 0] * float(baseline_m)
    return P


def reprojection_matrix(P_left, P_right) -> np.ndarray:
    """image_geometry's ``Q`` (4x4) of a rectified pair from the two REP 104 ``P`` matrices:
    ``[X Y Z W]^T = Q [u v d 1]^T`` with ``d`` a DisparityImage value, point ``(X, Y, Z) / W``
    in the left rectified optical frame (metres)."""
    Pl, Pr = np.asarray(P_left, np.float64), np.asarray(P_right, np.float64)
    fx, fy, cx, cy = Pl[0, 0], Pl[1, 1], Pl[0, 2], Pl[1, 2]
    if not (fx > 0 and fy > 0 and Pr[0, 0] > 0):
        raise RigError("the rectified camera has no focal length (uncalibrated CameraInfo)")
    Tx = Pr[0, 3] / Pr[0, 0]  # = -baseline
    if not Tx < 0:
        raise RigError("the right rectified camera has no baseline (P[0, 3] must be < 0)")
    Q = np.zeros((4, 4))
    Q[0, 0] = fy * Tx
    Q[0, 3] = -fy * cx * Tx
    Q[1, 1] = fx * Tx
    Q[1, 3] = -fx * cy * Tx
    Q[2, 3] = fx * fy * Tx
    Q[3, 2] = -fy
    Q[3, 3] = fy * (cx - Pr[0, 2])
    return Q


def reproject_disparity(disp, Q) -> np.ndarray:
    """Points (H, W, 3) float64 in the left rectified optical frame (metres) from
    message-convention disparities (H, W) through ``Q`` (NaN or ``<= 0`` = invalid -> NaN
    point): ``[X Y Z W]^T = Q [u v d 1]^T`` as image_geometry's ``projectDisparityTo3d``."""
    d = np.asarray(disp, np.float64)
    h, w = d.shape
    Q = np.asarray(Q, np.float64)
    u = np.arange(w, dtype=np.float64)[None, :]
    v = np.arange(h, dtype=np.float64)[:, None]
    valid = d > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_w = 1.0 / np.where(valid, Q[3, 2] * d + Q[3, 3], np.nan)
    out = np.empty((h, w, 3))
    np.multiply(Q[0, 0] * u + Q[0, 3], inv_w, out=out[..., 0])
    np.multiply(Q[1, 1] * v + Q[1, 3], inv_w, out=out[..., 1])
    np.multiply(Q[2, 3], inv_w, out=out[..., 2])
    out[~(out[..., 2] > 0)] = np.nan
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def _reproject_kernel(disp, mask, Q, T, organized, out, out_bits, rgb_bits, bgr, depth,
                      index):  # pragma: no cover - compiled
    # disp: (H, W) float32, any strides (a window of the message's map); mask: (H, W) uint8, any
    # strides, or (0, 0) for none; out: (H * W, C) float32 rows x, y, z[, rgb]; out_bits: the
    # same memory as uint32; rgb_bits: (H, W) uint32 packed colours copied into column 3, or
    # (0, 0); bgr: (H, W, 3) uint8 colours packed into column 3 (0x00RRGGBB) instead, or
    # (0, 0, 3); depth: (H, W) float32 filled with Z (NaN where no point), or (0, 0) for none;
    # index: (H * W,) int32 flat pixel indices of the rows, or (0,) for none.
    # Only the pixels that can hold a point are computed: outside the mask and where the
    # disparity is invalid nothing is (the arithmetic of a kept point is the same as before).
    h, w = disp.shape
    use_mask = mask.shape[0] == h
    with_rgb = rgb_bits.shape[0] == h
    with_bgr = bgr.shape[0] == h
    with_depth = depth.shape[0] == h
    with_index = index.shape[0] > 0
    q00, q03, q11, q13, q23, q32, q33 = Q[0, 0], Q[0, 3], Q[1, 1], Q[1, 3], Q[2, 3], Q[3, 2], Q[3, 3]
    t00, t01, t02, t03 = T[0, 0], T[0, 1], T[0, 2], T[0, 3]
    t10, t11, t12, t13 = T[1, 0], T[1, 1], T[1, 2], T[1, 3]
    t20, t21, t22, t23 = T[2, 0], T[2, 1], T[2, 2], T[2, 3]
    nan = np.float32(np.nan)
    n = 0
    for v in range(h):
        yv = q11 * v + q13
        for u in range(w):
            ok = not use_mask or mask[v, u] != 0
            d = disp[v, u]
            ok = ok and d > 0
            if ok:
                iw = 1.0 / (q32 * d + q33)
                z = q23 * iw
                ok = z > 0 and z < np.inf
                if ok:
                    x = (q00 * u + q03) * iw
                    y = yv * iw
                    if with_depth:
                        depth[v, u] = z
                    out[n, 0] = t00 * x + t01 * y + t02 * z + t03
                    out[n, 1] = t10 * x + t11 * y + t12 * z + t13
                    out[n, 2] = t20 * x + t21 * y + t22 * z + t23
            if not ok:
                if with_depth:
                    depth[v, u] = nan
                if not organized:
                    continue
                out[n, 0] = out[n, 1] = out[n, 2] = nan
            if with_rgb:
                out_bits[n, 3] = rgb_bits[v, u]
            elif with_bgr:
                b, g, r = np.uint32(bgr[v, u, 0]), np.uint32(bgr[v, u, 1]), np.uint32(bgr[v, u, 2])
                out_bits[n, 3] = (r << 16) | (g << 8) | b
            if with_index:
                index[n] = v * w + u
            n += 1
    return n


def _reproject(disp, Q, T, mask, organized, rgb, bgr=None, *, with_depth=True, with_index=True):
    d = np.asarray(disp)
    if d.ndim != 2:
        raise ValueError(f"disparity must be (H, W), got shape {d.shape}")
    if d.dtype != np.float32:
        d = d.astype(np.float32)
    m = kernel_mask(mask, d.shape, contiguous=False)
    T = np.eye(4) if T is None else np.asarray(T, np.float64)
    if rgb is None:
        bits = np.zeros((0, 0), np.uint32)
    else:
        bits = np.ascontiguousarray(rgb, np.float32)
        if bits.shape != d.shape:
            raise ValueError(f"rgb {bits.shape} does not match disparity {d.shape}")
        bits = bits.view(np.uint32)
    if bgr is None:
        colours = np.zeros((0, 0, 3), np.uint8)
    else:
        colours = np.asarray(bgr)
        if colours.dtype != np.uint8 or colours.shape != (*d.shape, 3):
            raise ValueError(f"bgr must be uint8 {(*d.shape, 3)}, got {colours.dtype} {colours.shape}")
    coloured = rgb is not None or bgr is not None
    out = np.empty((d.size, 4 if coloured else 3), np.float32)
    depth = np.empty(d.shape if with_depth else (0, 0), np.float32)
    index = np.empty(d.size if with_index else 0, np.int32)
    n = _reproject_kernel(d, m, np.asarray(Q, np.float64), T, bool(organized), out, out.view(np.uint32), bits,
                          colours, depth, index)
    return out[:n], (index[:n] if with_index else None), (depth if with_depth else None)


def reproject_disparity_points(disp, Q, *, T=None, mask=None, organized: bool = False):
    """One compiled pass of :func:`reproject_disparity` + a rigid transform, for a live node.

    Args:
        disp: (H, W) message-convention disparities (NaN or ``<= 0`` = invalid).
        Q: image_geometry's 4x4 reprojection matrix (:func:`reprojection_matrix`).
        T: 4x4 transform applied to the optical-frame points (None: identity).
        mask: optional (H, W); pixels where it is 0 get no point and no depth.
        organized: keep every pixel (NaN where none) instead of only valid ones.

    Returns ``(points, index, depth)``: float32 (N, 3) transformed points (metres), int32
    (N,) flat pixel indices ``v * W + u``, and float32 (H, W) depth ``Z`` in the optical
    frame (NaN where no point: the REP 118 depth image of the same pixels).
    """
    return _reproject(disp, Q, T, mask, organized, None)


def reproject_disparity_records(disp, Q, *, T=None, rgb=None, bgr=None, mask=None, organized: bool = False,
                                depth: bool = True):
    """:func:`reproject_disparity_points` writing PointCloud2 records directly: each row is
    float32 ``x, y, z`` (metres) and the packed ``rgb`` of its pixel, the layout of
    :func:`canopy_stereo.ros.convert.points_to_cloud2` (no gathering, stacking or copying
    afterwards: the rows become the message's data with one copy).

    Args:
        rgb: float32 (H, W) packed colours (:func:`canopy_stereo.ros.convert.pack_bgr_image`),
            copied bit for bit; or
        bgr: uint8 (H, W, 3) colours (any strides, e.g. a window of the rectified image),
            packed for the kept points only (the same bits as ``rgb=pack_bgr_image(bgr)``).
            Exactly one of the two.
        disp, Q, T, mask, organized: as :func:`reproject_disparity_points` (``disp`` and
            ``mask`` may be windows of larger arrays: they are read in place).
        depth: also build the depth image (False: None is returned in its place, and the
            pixels without a point cost nothing but their test).

    Only the pixels that can hold a point are computed: outside ``mask`` and where the
    disparity is invalid, a pixel is tested and skipped.

    Returns ``(records, depth)``: float32 (N, 4) (N = H * W when ``organized``, NaN
    coordinates where no point) and the float32 (H, W) depth image (or None).
    """
    if (rgb is None) == (bgr is None):
        raise ValueError("give the colours as exactly one of rgb (packed) and bgr (uint8 H x W x 3)")
    records, _, depth_image = _reproject(disp, Q, T, mask, organized, rgb, bgr, with_depth=bool(depth),
                                         with_index=False)
    return records, depth_image


@dataclass(frozen=True)
class FrameNames:
    """Frame ids of one rig's frames (defaults: :data:`DEFAULT_FRAMES`).

    Attributes:
        world: the rig's world frame; world_z_up: its z-up view ("" = none);
        raw_left, raw_right: the raw cameras' optical frames;
        rect_left, rect_right: the rectified cameras' optical frames;
        parent: the robot frame the rig is mounted on ("" = none: the world frame is a root).
    """

    world: str = WORLD_FRAME
    world_z_up: str = WORLD_Z_UP_FRAME
    raw_left: str = DEFAULT_FRAMES[("raw", "left")]
    raw_right: str = DEFAULT_FRAMES[("raw", "right")]
    rect_left: str = DEFAULT_FRAMES[("rect", "left")]
    rect_right: str = DEFAULT_FRAMES[("rect", "right")]
    parent: str = ""


#: The fields of :class:`FrameNames` that name the rig's own frames (prefixed by ``frame_prefix``).
RIG_FRAME_FIELDS = ("world", "world_z_up", "raw_left", "raw_right", "rect_left", "rect_right")


def prefixed_frames(names: FrameNames, prefix: str) -> FrameNames:
    """``names`` with ``prefix`` prepended to every frame the rig names (not to ``parent``,
    the robot's frame; empty names stay empty): ``rig_a/`` + ``canopy_world`` ->
    ``rig_a/canopy_world``. A prefix is a frame-id fragment: no spaces, no leading ``/``
    (tf2 rejects frame ids starting with one)."""
    prefix = str(prefix or "")
    if prefix.startswith("/") or any(c.isspace() for c in prefix):
        raise RigError(f"frame_prefix must not start with '/' or hold spaces, got {prefix!r}")
    values = {f: getattr(names, f) for f in RIG_FRAME_FIELDS}
    return FrameNames(**{f: (prefix + v if v else v) for f, v in values.items()}, parent=names.parent)


def pose_matrix(values, *, name: str = "mount") -> np.ndarray:
    """4x4 transform of seven numbers ``x y z qx qy qz qw`` (metres; ROS quaternion order),
    ``T_parent_child``. Raises :class:`RigError` naming ``name`` on a wrong count, a
    non-finite number or a quaternion whose norm is not 1 (within 1e-3)."""
    try:
        v = np.asarray([float(x) for x in values], np.float64)
    except (TypeError, ValueError):
        raise RigError(f"{name} must be seven numbers x y z qx qy qz qw, got {values!r}") from None
    if v.shape != (7,) or not np.all(np.isfinite(v)):
        raise RigError(f"{name} must be seven finite numbers x y z qx qy qz qw (metres, quaternion), "
                       f"got {len(v)} number(s)")
    n = np.linalg.norm(v[3:])
    if abs(n - 1.0) > 1e-3:
        raise RigError(f"{name}: the quaternion qx qy qz qw must have norm 1, got {n:.6g}")
    T = np.eye(4)
    T[:3, :3] = quaternion_to_rotation(v[3:])
    T[:3, 3] = v[:3]
    return T


def pose_values(T) -> list[float]:
    """Seven numbers ``x y z qx qy qz qw`` of a 4x4 rigid transform (inverse of :func:`pose_matrix`)."""
    T = np.asarray(T, np.float64)
    return [float(x) for x in T[:3, 3]] + [float(x) for x in rotation_to_quaternion(T[:3, :3])]


def mount_transform(rig, *, mount=None, camera_mount=None) -> np.ndarray:
    """``T_parent_world`` (4x4, metres): where the rig's world frame sits in the robot frame.

    Args:
        rig: the rig (its left camera's pose in its world frame, for ``camera_mount``).
        mount: seven numbers ``x y z qx qy qz qw``: the rig's world frame in the parent.
        camera_mount: seven numbers: the raw left camera's optical frame in the parent (what a
            hand-eye calibration gives); the world frame follows through the rig's ``P_left``.

    Exactly one of ``mount``/``camera_mount`` may be given; neither = identity.
    """
    if mount is not None and camera_mount is not None:
        raise RigError("give the rig's mount or the left camera's mount (camera_mount), not both")
    if camera_mount is not None:
        T_parent_cam = pose_matrix(camera_mount, name="camera_mount")
        T_world_cam = stereo_extrinsics(rig)[("raw", "left")]
        return T_parent_cam @ invert_transform(T_world_cam)
    return np.eye(4) if mount is None else pose_matrix(mount, name="mount")


def stereo_transforms(rig, rect=None, *, names: FrameNames | None = None,
                      mount=None) -> list[tuple[str, str, np.ndarray]]:
    """The static transforms of a rig as ``(parent, child, T_parent_child)`` (4x4, metres).

    One tree: ``world_z_up -> world -> {raw_left, raw_right, rect_left, rect_right}``
    (the rectified frames only for a calibrated rectification ``rect``; ``world_z_up``
    only when named). Mounted (``names.parent`` set): ``parent -> world -> {the cameras,
    world_z_up}`` with ``T_parent_world = mount`` (4x4; None = identity,
    :func:`mount_transform`).
    """
    names = names or FrameNames()
    out = []
    if names.parent:
        out.append((names.parent, names.world, np.eye(4) if mount is None else np.asarray(mount, np.float64)))
        if names.world_z_up:
            out.append((names.world, names.world_z_up, invert_transform(world_z_up_transform(rig))))
    elif names.world_z_up:
        out.append((names.world_z_up, names.world, world_z_up_transform(rig)))
    ext = stereo_extrinsics(rig, rect)
    for (kind, side), T in ext.items():
        child = getattr(names, f"{kind}_{side}")
        if child:
            out.append((names.world, child, T))
    return out
