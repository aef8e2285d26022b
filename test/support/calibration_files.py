# ruff: noqa: UP031 - the ROS writers below keep calibrator.py's own %-formatting, digit for digit
"""Calibration files written the way each tool writes them, from a known (true) rig.

* ROS ``camera_calibration``: ``lryaml``/``lrost`` of image_pipeline's calibrator.py (its
  number formatting: ``%8f`` distortion, ``array2string`` precision 5 for K and P, 8 for R;
  ``R``/``P`` from ``cv2.stereoRectify`` with ``CALIB_ZERO_DISPARITY``, alpha 0 as it
  does; translations in metres);
* Kalibr ``camchain.yaml`` (yaml.dump of its dictionary; ``T_cn_cnm1`` in metres);
* OpenCV's ``stereo_calib`` sample: ``cv::FileStorage`` with ``M1 D1 M2 D2 R T R1 R2 P1 P2 Q``
  written by ``cv2.FileStorage`` itself (YAML or XML);
* Middlebury 2014 ``calib.txt``.

The true rig's world frame is the left camera's optical frame, in millimetres.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import yaml

from canopy_stereo.geometry.camera import decompose_projection
from canopy_stereo.geometry.rig import Rig


def verged_rig(*, D_left, D_right, size=(640, 480), model=None, baseline_mm=60.0, toe_in_deg=2.0,
               skew=0.0) -> Rig:
    """Two cameras ``baseline_mm`` apart, each turned ``toe_in_deg`` towards the other,
    slightly different intrinsics, world = left optical frame (mm)."""
    w, h = size
    s = w / 640.0
    K1 = np.array([[520.0 * s, skew, 322.5 * s], [0, 518.0 * s, 236.0 * s], [0, 0, 1]])
    K2 = np.array([[512.0 * s, 0, 317.0 * s], [0, 511.0 * s, 243.5 * s], [0, 0, 1]])
    a = np.deg2rad(2 * toe_in_deg)
    R = cv2.Rodrigues(np.array([0.004, a, 0.006]))[0]    # right camera turned towards the left, a bit rolled
    C = np.array([baseline_mm, 1.5, -2.0])             # right centre in the left frame
    T = -R @ C
    return Rig(P_left=K1 @ np.hstack([np.eye(3), np.zeros((3, 1))]), P_right=K2 @ np.hstack([R, T[:, None]]),
               image_size=size, world_unit="mm", D_left=D_left, D_right=D_right, distortion_model=model)


def stereo_parts(rig: Rig):
    """``K1, D1, K2, D2, R, T (mm)`` of a rig whose world frame is the left camera."""
    cl, cr = decompose_projection(rig.P_left), decompose_projection(rig.P_right)
    assert np.allclose(cl.R, np.eye(3)) and np.allclose(cl.C, 0)
    return cl.K, rig.D_left, cr.K, rig.D_right, cr.R, -cr.R @ cr.C


def _ros_rectification(rig: Rig):
    K1, D1, K2, D2, R, T = stereo_parts(rig)
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K1, D1, K2, D2, rig.image_size, R, (T / 1000.0).reshape(3, 1),
                                           flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    return (K1, D1, R1, P1), (K2, D2, R2, P2)


def _lryaml(name, d, k, r, p, size, model):  # calibrator.py's lryaml
    def format_mat(x, precision):
        return ("[%s]" % (np.array2string(x, precision=precision, suppress_small=True, separator=", ")
                          .replace("[", "").replace("]", "").replace("\n", "\n        ")))
    return "\n".join([
        "image_width: %d" % size[0], "image_height: %d" % size[1], "camera_name: " + name,
        "camera_matrix:", "  rows: 3", "  cols: 3", "  data: " + format_mat(k, 5),
        "distortion_model: " + model,
        "distortion_coefficients:", "  rows: 1", "  cols: %d" % d.size,
        "  data: [%s]" % ", ".join("%8f" % x for x in d.flat),
        "rectification_matrix:", "  rows: 3", "  cols: 3", "  data: " + format_mat(r, 8),
        "projection_matrix:", "  rows: 3", "  cols: 4", "  data: " + format_mat(p, 5), ""])


def _lrost(name, d, k, r, p, size):  # calibrator.py's lrost
    return "\n".join([
        "# oST version 5.0 parameters", "", "", "[image]", "", "width", "%d" % size[0], "", "height",
        "%d" % size[1], "", "[%s]" % name, "", "camera matrix",
        *(" ".join("%8f" % k[j, i] for i in range(3)) for j in range(3)), "", "distortion",
        " ".join("%8f" % x for x in d.flat), "", "rectification",
        *(" ".join("%8f" % r[j, i] for i in range(3)) for j in range(3)), "", "projection",
        *(" ".join("%8f" % p[j, i] for i in range(4)) for j in range(3)), ""])


def write_ros_yaml(rig: Rig, folder) -> list[Path]:
    folder = Path(folder)
    model = "plumb_bob" if rig.D_left.size <= 5 else "rational_polynomial"
    out = []
    for side, (k, d, r, p) in zip(("left", "right"), _ros_rectification(rig)):
        path = folder / f"{side}.yaml"
        path.write_text(_lryaml(f"narrow_stereo/{side}", np.asarray(d), k, r, p, rig.image_size, model))
        out.append(path)
    return out


def write_ros_ini(rig: Rig, folder) -> list[Path]:
    (k1, d1, r1, p1), (k2, d2, r2, p2) = _ros_rectification(rig)
    path = Path(folder) / "ost.txt"
    path.write_text(_lrost("narrow_stereo/left", np.asarray(d1), k1, r1, p1, rig.image_size)
                    + _lrost("narrow_stereo/right", np.asarray(d2), k2, r2, p2, rig.image_size))
    return [path]


def write_kalibr(rig: Rig, folder) -> list[Path]:
    K1, D1, K2, D2, R, T = stereo_parts(rig)
    model = "equidistant" if rig.distortion_model == "equidistant" else "radtan"
    Tm = np.eye(4)
    Tm[:3, :3], Tm[:3, 3] = R, T / 1000.0

    def cam(K, D, topic):
        return {"camera_model": "pinhole", "distortion_coeffs": [float(v) for v in np.asarray(D)[:4]],
                "distortion_model": model,
                "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
                "resolution": list(rig.image_size), "rostopic": topic}
    doc = {"cam0": {"cam_overlaps": [1], **cam(K1, D1, "/cam0/image_raw")},
           "cam1": {"T_cn_cnm1": [[float(v) for v in row] for row in Tm], "cam_overlaps": [0],
                    **cam(K2, D2, "/cam1/image_raw")}}
    path = Path(folder) / "camchain.yaml"
    path.write_text(yaml.dump(doc))
    return [path]


def write_opencv(rig: Rig, folder, ext: str = "yml") -> list[Path]:
    """The stereo_calib sample's two files (intrinsics + extrinsics), ``ext`` yml or xml."""
    K1, D1, K2, D2, R, T = stereo_parts(rig)
    R1, R2, P1, P2, Q, *_ = cv2.stereoRectify(K1, np.asarray(D1), K2, np.asarray(D2), rig.image_size, R,
                                              T.reshape(3, 1), flags=cv2.CALIB_ZERO_DISPARITY, alpha=-1)
    folder = Path(folder)
    paths = [folder / f"intrinsics.{ext}", folder / f"extrinsics.{ext}"]
    fs = cv2.FileStorage(str(paths[0]), cv2.FILE_STORAGE_WRITE)
    for name, m in (("M1", K1), ("D1", np.asarray(D1)[None]), ("M2", K2), ("D2", np.asarray(D2)[None])):
        fs.write(name, np.asarray(m, np.float64))
    fs.write("image_width", rig.image_size[0])
    fs.write("image_height", rig.image_size[1])
    fs.release()
    fs = cv2.FileStorage(str(paths[1]), cv2.FILE_STORAGE_WRITE)
    for name, m in (("R", R), ("T", T[:, None]), ("R1", R1), ("R2", R2), ("P1", P1), ("P2", P2), ("Q", Q)):
        fs.write(name, np.asarray(m, np.float64))
    fs.release()
    return paths


def write_middlebury(rig: Rig, folder, *, ndisp: int = 96) -> list[Path]:
    """calib.txt of a rectified rig (the right camera = the left shifted along x)."""
    K1, _, K2, _, R, T = stereo_parts(rig)
    assert np.allclose(R, np.eye(3)) and np.allclose(T[1:], 0)

    def cam(K):
        return f"[{K[0, 0]:.3f} 0 {K[0, 2]:.3f}; 0 {K[1, 1]:.3f} {K[1, 2]:.3f}; 0 0 1]"
    text = (f"cam0={cam(K1)}\ncam1={cam(K2)}\ndoffs={K2[0, 2] - K1[0, 2]:.3f}\nbaseline={-T[0]:.3f}\n"
            f"width={rig.image_size[0]}\nheight={rig.image_size[1]}\nndisp={ndisp}\nisint=0\nvmin=10\n"
            f"vmax={ndisp - 10}\ndyavg=0\ndymax=0\n")
    path = Path(folder) / "calib.txt"
    path.write_text(text)
    return [path]
