"""The bundled bags (``bags/``) and their rig files (``config/``): where they are, how they are made.

Scenes:

* ``croton``: the synthetic potted croton of :mod:`canopy_stereo.sim` seen
  through the paper's rig (640x480), several frames of a gentle breeze at
  10 frames/s, the right camera 4 ms behind the left (webcams are never in
  step). The bag also holds the truth: ``/truth/left/depth`` (16UC1,
  millimetres as in REP 118, 0 = nothing: depth along the left camera's
  optical axis at each original left pixel).
* ``plants``: the Middlebury 2014 "Plants" pair (quarter size, 710x496), a real
  potted plant, with its calibration as a rig (Scharstein et al., GCPR 2014).

Stereo frames are on ``/stereo/left/image_raw`` and ``/stereo/right/image_raw``
(bgr8). ``bags/make_bags.py`` regenerates everything.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.frames import FrameNames, stereo_info_frame
from canopy_stereo.io.rig import Rig, save_rig

#: scene -> (bag file, rig file)
BUNDLED = {"croton": ("croton.mcap", "croton_rig.yaml"), "plants": ("plants.mcap", "plants_rig.yaml")}

LEFT_TOPIC = "/stereo/left/image_raw"
RIGHT_TOPIC = "/stereo/right/image_raw"
TRUTH_DEPTH_TOPIC = "/truth/left/depth"
#: frame_id of both raw images (and the truth depth): the left camera's optical frame, the
#: frame rectify_node's /tf_static names and camera_node uses for a stereo pair
#: (:func:`canopy_stereo.geometry.frames.stereo_info_frame`).
RAW_FRAME = stereo_info_frame(FrameNames(), "raw")

#: Stamp of the first frame of the bundled bags (2024-01-01T00:00:00Z), ns.
EPOCH_NS = 1_704_067_200_000_000_000


def _share_dir() -> Path | None:
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("canopy_stereo"))
    except (ImportError, LookupError, ValueError, OSError, KeyError):
        return None


def _find(kind: str, name: str) -> Path:
    import sys

    source_tree = Path(__file__).resolve().parents[2] / kind / name
    if source_tree.is_file():
        return source_tree
    for share in (_share_dir(), Path(sys.prefix) / "share" / "canopy_stereo"):
        if share is not None and (share / kind / name).is_file():
            return share / kind / name
    raise CanopyStereoError(f"bundled file {kind}/{name} not found (source tree or share/canopy_stereo)")


def bundled_scenes() -> list[str]:
    """Names of the bundled scenes."""
    return list(BUNDLED)


def bundled_bag(scene: str) -> Path:
    """Path of the bundled bag of ``scene``."""
    if scene not in BUNDLED:
        raise CanopyStereoError(f"no bundled scene {scene!r}; choose {', '.join(BUNDLED)}")
    return _find("bags", BUNDLED[scene][0])


def bundled_rig(scene: str) -> Path:
    """Path of the rig file of ``scene``'s bundled bag."""
    if scene not in BUNDLED:
        raise CanopyStereoError(f"no bundled scene {scene!r}; choose {', '.join(BUNDLED)}")
    return _find("config", BUNDLED[scene][1])


def write_stereo_bag(path, frames, *, truth_depths=None, compression: str = "zstd",
                     metadata: dict | None = None, rig: Rig | None = None, image_format: str = "raw",
                     jpeg_quality: int = 95, jpegs=None) -> Path:
    """Write stereo frames (and optional truth depth maps) as a bag.

    Args:
        path: output ``.mcap``.
        frames: iterable of ``(left_bgr, right_bgr, left_stamp_ns, right_stamp_ns)``.
        truth_depths: optional list of float (H, W) depth maps (metres, NaN = nothing),
            one per frame, stamped like the left image, on :data:`TRUTH_DEPTH_TOPIC`
            as 16UC1 millimetres (REP 118; 0 = nothing). Rounding to 0.5 mm is
            below 0.1 % of the scene's depth and keeps the bag small.
        metadata, rig: optional ``canopy_stereo`` KEY=VALUE metadata and rig, stored
            as the bag's metadata records (:mod:`canopy_stereo.bag.metadata`).
        image_format: ``"raw"`` (bgr8 ``Image`` on :data:`LEFT_TOPIC`, :data:`RIGHT_TOPIC`),
            or ``"jpeg"`` / ``"png"``: ``CompressedImage`` on image_transport's
            ``<topic>/compressed`` only, as robot bags usually hold them
            (:mod:`canopy_stereo.io.compressed_image`).
        jpeg_quality: JPEG quality (1-100) of ``image_format="jpeg"``.
        jpegs: optional list of ``(left JPEG bytes, right JPEG bytes)``, one per frame (a
            camera's MJPEG frames, e.g. the simulator's): stored as they are, as
            ``CompressedImage`` on ``<topic>/compressed`` (format ``bgr8; jpeg compressed bgr8``),
            whatever ``image_format``.
    """
    from canopy_stereo.bag import BagWriter
    from canopy_stereo.bag.metadata import recording_metadata
    from canopy_stereo.io.compressed_image import (
        COMPRESSED_IMAGE_TYPE,
        compressed_image_cdr,
        compressed_topic,
        encode_frame_cdr,
    )
    from canopy_stereo.io.image_codec import DEVICE_JPEG_FORMAT
    from canopy_stereo.ros.convert import image_to_msg

    if image_format not in ("raw", "jpeg", "png"):
        raise CanopyStereoError(f"image_format must be raw, jpeg or png, got {image_format!r}")
    frame = RAW_FRAME

    def write_image(bag, topic, image, stamp_ns, log_ns, jpeg=None):
        if jpeg is not None:  # a camera's own JPEG bytes, stored as they are
            cdr = compressed_image_cdr(stamp_ns=stamp_ns, frame_id=frame, fmt=DEVICE_JPEG_FORMAT, data=jpeg)
        elif image_format == "raw":
            bag.write(topic, image_to_msg(image, "bgr8", stamp_ns=stamp_ns, frame_id=frame), log_ns)
            return
        else:
            cdr = encode_frame_cdr(image, stamp_ns=stamp_ns, frame_id=frame, codec=image_format,
                                   quality=jpeg_quality)
        bag.write(compressed_topic(topic), cdr, log_ns, publish_time_ns=stamp_ns, msg_type=COMPRESSED_IMAGE_TYPE)

    transport_ns = 2_000_000  # reception 2 ms after capture
    with BagWriter(path, compression=compression,
                   metadata=recording_metadata(metadata, rig)) as bag:
        for k, (left, right, t_left, t_right) in enumerate(frames):
            jpeg = jpegs[k] if jpegs is not None else (None, None)
            write_image(bag, LEFT_TOPIC, left, t_left, t_left + transport_ns, jpeg[0])
            write_image(bag, RIGHT_TOPIC, right, t_right, t_right + transport_ns, jpeg[1])
            if truth_depths is not None:
                depth_mm = np.rint(np.nan_to_num(np.asarray(truth_depths[k], np.float64) * 1000.0,
                                                 nan=0.0)).clip(0, 65535).astype(np.uint16)
                bag.write(TRUTH_DEPTH_TOPIC, image_to_msg(depth_mm, "16UC1", stamp_ns=t_left,
                                                          frame_id=frame),
                          t_left + transport_ns + 1)
    return Path(path)


def croton_frames(rig: Rig, n_frames: int = 4, *, seed: int = 0, fps: float = 10.0,
                  right_lag_s: float = 0.004):
    """Render the croton scene: ``(frames, truth depths (m), disparity range (px))``.

    The range is the rectified (Fusiello) disparity span of the truth over all
    frames, widened by 6 pixels each side.
    """
    from canopy_stereo.geometry.camera import point_depth, project
    from canopy_stereo.geometry.rectification import fusiello_rectify
    from canopy_stereo.sim import render_scene

    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    frames, depths, dmin, dmax = [], [], np.inf, -np.inf
    period = int(round(1e9 / fps))
    for k in range(n_frames):
        sim = render_scene("croton", rig, seed=seed, frame=k)
        t_left = EPOCH_NS + k * period
        frames.append((sim.left, sim.right, t_left, t_left + int(round(right_lag_s * 1e9))))
        xyz = sim.xyz_left.reshape(-1, 3)
        ok = np.all(np.isfinite(xyz), axis=1)
        depth = np.full(len(xyz), np.nan)
        depth[ok] = point_depth(rig.P_left, xyz[ok]) * rig.metres_per_unit
        depths.append(depth.reshape(sim.xyz_left.shape[:2]).astype(np.float32))
        d = project(rect.P_rect_left, xyz[ok])[:, 0] - project(rect.P_rect_right, xyz[ok])[:, 0]
        dmin, dmax = min(dmin, float(d.min())), max(dmax, float(d.max()))
    return frames, depths, (max(0, int(np.floor(dmin)) - 6), int(np.ceil(dmax)) + 6)


def make_croton(bag_path, rig_path, paper_rig: Rig, *, n_frames: int = 4, seed: int = 0) -> tuple[Path, Path]:
    """Render and write the croton bag and its rig file (the paper rig with the
    disparity range of the scene and sub-pixel ELAS)."""
    frames, depths, (dmin, dmax) = croton_frames(paper_rig, n_frames, seed=seed)
    rig = paper_rig.with_extra(disp_min=dmin, disp_max=dmax, elas={"subpixel": True})
    write_stereo_bag(bag_path, frames, truth_depths=depths, rig=rig)  # the rig in the bag: batch needs no --rig
    save_rig(rig, rig_path, comment=(
        "The paper's rig (config/paper_rig.yaml) for the bundled synthetic croton bag "
        "(bags/croton.mcap),\nwith the scene's disparity range (f B / Z of the Fusiello rectification: "
        "0 at infinity) and sub-pixel ELAS."))
    return Path(bag_path), Path(rig_path)


def make_plants(bag_path, rig_path, scene_folder) -> tuple[Path, Path]:
    """Write the Middlebury 2014 Plants pair as a one-frame bag and its rig file
    (world frame = left camera, millimetres; disparity range from ``ndisp``)."""
    from canopy_stereo.geometry.rectification import fusiello_rectify
    from canopy_stereo.io.images import read_image
    from canopy_stereo.io.middlebury import read_middlebury_calib, rig_from_middlebury

    folder = Path(scene_folder)
    calib = read_middlebury_calib(folder / "calib.txt")
    rig = rig_from_middlebury(calib)
    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    # The images are already rectified, with diverging principal points: the rectification
    # keeps them (identity homographies, doffs = cx0 - cx1), so Middlebury disparities
    # d_mb in [0, ndisp) stay d_mb + (cx1 - cx0) + (cx0' - cx1') = d_mb (' rectified).
    shift = float(calib["cam1"][0, 2] - calib["cam0"][0, 2]) + rect.doffs
    ndisp = int(calib.get("ndisp", 128))
    dmin, dmax = max(0, int(np.floor(shift)) - 1), int(np.ceil(shift + ndisp)) + 1
    rig = rig.with_extra(disp_min=dmin, disp_max=dmax)
    left, right = read_image(folder / "im0.png"), read_image(folder / "im1.png")
    write_stereo_bag(bag_path, [(left, right, EPOCH_NS, EPOCH_NS)], rig=rig)
    save_rig(rig, rig_path, comment=(
        'Middlebury 2014 "Plants" (MiddEval3 test, quarter size; Scharstein et al., GCPR 2014).\n'
        f"World frame = left camera (cam0), millimetres; from calib.txt (baseline {calib['baseline']:g} mm, "
        f"doffs {calib.get('doffs', 0.0):g} px, ndisp {ndisp}).\n"
        "The pair is rectified already and kept as it is (doffs = cx_left - cx_right); "
        "disp_min/disp_max: Middlebury's d range."))
    return Path(bag_path), Path(rig_path)


def read_truth_depths(bag_path) -> dict:
    """Left stamp (ns) -> truth depth map (float32 (H, W), metres, NaN = nothing)
    of a bag's :data:`TRUTH_DEPTH_TOPIC` (empty if it has none). Accepts 16UC1
    millimetres (REP 118) and 32FC1 metres."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.convert import msg_to_image, stamp_to_ns

    bag = BagReader(bag_path)
    if TRUTH_DEPTH_TOPIC not in bag.topics:
        return {}
    out = {}
    for _, m in bag.read(TRUTH_DEPTH_TOPIC):
        depth = msg_to_image(m, ("16UC1", "32FC1")).astype(np.float32)
        if m.encoding == "16UC1":
            depth = np.where(depth > 0, depth / 1000.0, np.nan).astype(np.float32)
        out[stamp_to_ns(m.header.stamp)] = depth
    return out


def relative_depth_errors(points_m: np.ndarray, rig: Rig, truth_depth: np.ndarray) -> np.ndarray:
    """``|Z - Z_true| / Z_true`` for each point of a cloud against a truth depth map.

    Args:
        points_m: (N, 3) world points in metres (a ``points2`` cloud).
        rig: the rig (world frame and unit of the truth).
        truth_depth: (H, W) depth along the left optical axis (metres) at each
            original left pixel.

    Each point is projected into the original left image; ``Z`` is its depth in
    front of the left camera and ``Z_true`` the truth at the nearest pixel.
    Points that project outside the image or onto pixels without truth are left out.
    """
    from canopy_stereo.geometry.camera import point_depth, project

    X = np.asarray(points_m, np.float64).reshape(-1, 3) / rig.metres_per_unit
    X = X[np.isfinite(X).all(axis=1)]
    uv = np.rint(project(rig.P_left, X)).astype(np.int64)
    h, w = truth_depth.shape
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    z = point_depth(rig.P_left, X[inside]) * rig.metres_per_unit
    z_true = truth_depth[uv[inside, 1], uv[inside, 0]].astype(np.float64)
    ok = np.isfinite(z_true) & (z_true > 0)
    return np.abs(z[ok] - z_true[ok]) / z_true[ok]
