"""Middlebury stereo data: ``calib.txt`` parsing, rig files and ground-truth disparities.

Depth from a Middlebury 2014 disparity: ``Z = baseline * f / (d + doffs)`` (mm).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import read_image
from canopy_stereo.io.pfm import read_pfm
from canopy_stereo.io.rig import Rig


def read_middlebury_calib(path, *, fields=None) -> dict:
    """Parse a Middlebury 2014 ``calib.txt``.

    Returns a dict with ``cam0``/``cam1`` as (3, 3) arrays and the scalars
    (``doffs``, ``baseline`` in mm, ``width``, ``height``, ``ndisp``, ...) as floats.
    Tolerates the irregular whitespace of the published files. ``fields``: the names
    allowed (any other is an error naming it, nearest name suggested); None = any.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise CanopyStereoError(f"cannot read {path}: {exc.strerror or exc}") from None
    out: dict = {}
    for line in text.splitlines():
        if "=" not in line:
            continue
        key, value = (s.strip() for s in line.split("=", 1))
        if fields is not None and key not in fields:
            from canopy_stereo.io.calibration_import.stereo import unknown_field

            raise unknown_field(str(path), key, fields)
        if key.startswith("cam"):
            nums = [float(v) for v in re.split(r"[\s;\[\]]+", value) if v]
            if len(nums) != 9:
                raise CanopyStereoError(f"{path}: {key} must hold 9 numbers")
            out[key] = np.array(nums).reshape(3, 3)
        else:
            try:
                out[key] = float(value)
            except ValueError:
                out[key] = value
    for key in ("cam0", "cam1", "baseline", "width", "height"):
        if key not in out:
            raise CanopyStereoError(f"{path}: missing {key}")
    out.setdefault("doffs", float(out["cam1"][0, 2] - out["cam0"][0, 2]))
    return out


def rig_from_middlebury(calib: dict | str | Path) -> Rig:
    """A rig in millimetres whose world frame is the left (cam0) camera frame.

    ``P_left = K0 [I | 0]`` and ``P_right = K1 [I | (-baseline, 0, 0)]``. When
    ``calib`` has ``ndisp``, the rig carries the search range ``disp_min``/
    ``disp_max`` for the Fusiello-rectified pair (:func:`middlebury_disparity_range`).
    """
    if not isinstance(calib, dict):
        calib = read_middlebury_calib(calib)
    K0, K1, B = calib["cam0"], calib["cam1"], float(calib["baseline"])
    P_left = K0 @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = K1 @ np.hstack([np.eye(3), np.array([[-B], [0.0], [0.0]])])
    return Rig(P_left=P_left, P_right=P_right,
               image_size=(int(calib["width"]), int(calib["height"])), world_unit="mm",
               extra=middlebury_disparity_range(calib))


def middlebury_disparity_range(calib: dict) -> dict:
    """``{"disp_min", "disp_max"}`` (pixels) of the Fusiello-rectified pair for a parsed
    ``calib.txt`` with ``ndisp``, else ``{}``. A Middlebury pair is rectified already: when its
    principal points diverge (``doffs = cx1 - cx0 > 0``, as in every 2014 scene) the
    rectification keeps it and the disparities are Middlebury's ``d`` in ``[0, ndisp)``;
    otherwise they are ``d + doffs`` (one principal point)."""
    if "ndisp" not in calib:
        return {}
    from canopy_stereo.geometry.rectification import fusiello_rectify

    K0, K1, B = calib["cam0"], calib["cam1"], float(calib["baseline"])
    P0 = K0 @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P1 = K1 @ np.hstack([np.eye(3), np.array([[-B], [0.0], [0.0]])])
    rect = fusiello_rectify(P0, P1, (int(calib["width"]), int(calib["height"])))
    shift = float(K1[0, 2] - K0[0, 2]) + rect.doffs
    return {"disp_min": max(0, int(np.floor(shift)) - 1),
            "disp_max": int(np.ceil(shift + float(calib["ndisp"]))) + 1}


def read_disparity(path, scale: float | None = None) -> np.ndarray:
    """Read a ground-truth disparity as float32 (H, W), NaN where unknown.

    PFM files are read as is (``inf`` -> NaN). 8/16-bit PNG/PGM values are divided
    by ``scale`` (e.g. 4 for Middlebury 2003 quarter size, 16 for Tsukuba) and
    0 means unknown.
    """
    path = Path(path)
    if path.suffix.lower() == ".pfm":
        d = read_pfm(path)
        if d.ndim == 3:
            d = d[:, :, 0]
        d = d.astype(np.float32)
        d[~np.isfinite(d)] = np.nan
        return d
    import cv2

    if not path.is_file():
        raise CanopyStereoError(f"disparity file not found: {path}")
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise CanopyStereoError(f"cannot read disparity image {path}")
    if raw.ndim == 3:
        raw = raw[:, :, 0]
    if scale is None or scale <= 0:
        raise CanopyStereoError(f"{path}: an integer disparity image needs a positive scale")
    d = raw.astype(np.float32) / float(scale)
    d[raw == 0] = np.nan
    return d


def load_middlebury_2014(folder) -> dict:
    """Load a MiddEval3 scene folder: ``left``, ``right`` (BGR), ``calib``, ``rig``,
    ``disp`` (GT, NaN unknown, or None) and ``nonocc`` (bool mask or None)."""
    folder = Path(folder)
    calib = read_middlebury_calib(folder / "calib.txt")
    scene = {
        "left": read_image(folder / "im0.png"),
        "right": read_image(folder / "im1.png"),
        "calib": calib,
        "rig": rig_from_middlebury(calib),
        "disp": None,
        "nonocc": None,
    }
    if (folder / "disp0GT.pfm").is_file():
        scene["disp"] = read_disparity(folder / "disp0GT.pfm")
    if (folder / "mask0nocc.png").is_file():
        scene["nonocc"] = read_image(folder / "mask0nocc.png", color=False) == 255
    return scene
