"""``calibrate --from``: calibration files written as ROS camera_calibration, Kalibr, OpenCV's
stereo_calib sample and Middlebury write them, for a verged rig with lens distortion
(rectified and distortion-free for Middlebury, which can hold nothing else), import to a rig
that projects and reconstructs as the true cameras do; bad files are one line, exit 2."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.camera import point_depth, project
from canopy_stereo.geometry.distortion import distort_pixels
from canopy_stereo.geometry.rig import Rig
from canopy_stereo.io.calibration_import import import_calibration
from canopy_stereo.io.rig import load_rig
from test.conftest import run_cli_subprocess
from test.support.calibration_files import (
    verged_rig,
    write_kalibr,
    write_middlebury,
    write_opencv,
    write_ros_ini,
    write_ros_yaml,
)

PLUMB_BOB = ([-0.21, 0.08, 0.0011, -0.0007, -0.015], [-0.18, 0.05, -0.0006, 0.0009, 0.01])
RATIONAL = ([-0.30, 0.11, 0.0011, -0.0007, 0.02, 0.05, 0.01, 0.003],
            [-0.25, 0.09, -0.0006, 0.0009, 0.01, 0.04, 0.0, 0.002])
RADTAN = ([-0.21, 0.08, 0.0011, -0.0007], [-0.18, 0.05, -0.0006, 0.0009])
FISHEYE = ([0.05, -0.01, 0.003, -0.001], [0.04, -0.008, 0.002, 0.0])


def _rectified_rig() -> Rig:
    K1 = np.array([[560.0, 0, 318.0], [0, 560.0, 241.0], [0, 0, 1]])
    K2 = K1.copy()
    K2[0, 2] = 326.0
    return Rig(P_left=np.hstack([K1, np.zeros((3, 1))]), P_right=K2 @ np.hstack([np.eye(3), [[-60.0], [0], [0]]]),
               image_size=(640, 480), world_unit="mm")


#: case -> (true rig, format, writer)
CASES = {
    "ros-yaml plumb_bob": (lambda: verged_rig(D_left=PLUMB_BOB[0], D_right=PLUMB_BOB[1]), "ros-yaml", write_ros_yaml),
    "ros-yaml rational": (lambda: verged_rig(D_left=RATIONAL[0], D_right=RATIONAL[1]), "ros-yaml", write_ros_yaml),
    "ros-ini ost.txt": (lambda: verged_rig(D_left=PLUMB_BOB[0], D_right=PLUMB_BOB[1]), "ros-ini", write_ros_ini),
    "kalibr radtan": (lambda: verged_rig(D_left=RADTAN[0], D_right=RADTAN[1]), "kalibr", write_kalibr),
    "kalibr equidistant": (lambda: verged_rig(D_left=FISHEYE[0], D_right=FISHEYE[1], model="equidistant"),
                           "kalibr", write_kalibr),
    "opencv yaml": (lambda: verged_rig(D_left=RATIONAL[0], D_right=RATIONAL[1]), "opencv",
                    lambda rig, d: write_opencv(rig, d, "yml")),
    "opencv xml": (lambda: verged_rig(D_left=RATIONAL[0], D_right=RATIONAL[1]), "opencv",
                   lambda rig, d: write_opencv(rig, d, "xml")),
    "middlebury": (_rectified_rig, "middlebury", write_middlebury),
}


def _import(case, tmp_path):
    make, fmt, writer = CASES[case]
    true = make()
    return true, import_calibration(fmt, writer(true, tmp_path))


def projection_errors(true: Rig, got: Rig, *, n: int = 5000, seed: int = 0) -> np.ndarray:
    """Pixel distances (2n,) between where the true and the imported cameras show points
    spread over the left view at 0.3-2 m (distorted pixels, both cameras)."""
    rng = np.random.default_rng(seed)
    w, h = true.image_size
    uv = rng.uniform([0, 0], [w, h], (n, 2))
    z_mm = rng.uniform(300, 2000, n)
    K = true.P_left[:, :3]
    X_mm = np.linalg.solve(K, np.c_[uv, np.ones(n)].T).T * z_mm[:, None]
    X_got = X_mm * (0.001 / got.metres_per_unit)
    errs = []
    for side in ("left", "right"):
        Pt, Dt = getattr(true, f"P_{side}"), getattr(true, f"D_{side}")
        Pg, Dg = getattr(got, f"P_{side}"), getattr(got, f"D_{side}")
        a = distort_pixels(Pt, Dt, project(Pt, X_mm), model=true.distortion_model)
        b = distort_pixels(Pg, Dg, project(Pg, X_got), model=got.distortion_model)
        errs.append(np.linalg.norm(a - b, axis=1))
    return np.concatenate(errs)


@pytest.mark.parametrize("case", list(CASES))
def test_imported_rig_projects_where_the_true_cameras_do(case, tmp_path):
    true, got = _import(case, tmp_path)
    assert got.distortion_model == (true.distortion_model if case != "middlebury" else "plumb_bob")
    assert got.world_unit == {"ros-yaml": "m", "ros-ini": "m", "kalibr": "m"}.get(CASES[case][1], "mm")
    err = projection_errors(true, got)
    assert np.percentile(err, 95) <= 0.5
    assert np.percentile(err, 95) <= 0.01   # what the files' rounding allows (measured 2e-6 .. 4e-4 px)
    assert got.baseline * got.metres_per_unit == pytest.approx(true.baseline * true.metres_per_unit, rel=1e-4)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["ros-yaml plumb_bob", "ros-ini ost.txt", "kalibr radtan", "kalibr equidistant",
                                  "opencv yaml", "opencv xml", "middlebury"])
def test_imported_rig_reconstructs_the_scene(case, tmp_path, rendered):
    """The simulator renders the croton through the TRUE cameras (their lens model); the
    pipeline reconstructs it with the IMPORTED rig: median depth error <= 0.5 %."""
    true, got = _import(case, tmp_path)
    sim = rendered(true)
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rec = reconstruct_pair(sim.left, sim.right, got)
    leaf = sim.leaf_ids_left > 0
    ok = leaf & np.all(np.isfinite(rec.organized), axis=2)
    assert ok.sum() >= 0.8 * leaf.sum()
    true_mm = point_depth(true.P_left, sim.xyz_left[ok])
    got_mm = point_depth(got.P_left, rec.organized[ok]) * got.metres_per_unit * 1000.0
    rel = np.abs(got_mm - true_mm) / true_mm
    assert np.median(rel) <= 0.005


@pytest.fixture(scope="module")
def rendered():
    from canopy_stereo.sim import render_scene

    cache = {}

    def render(rig):
        key = rig.P_right.tobytes() + rig.D_left.tobytes() + rig.distortion_model.encode()
        if key not in cache:
            cache[key] = render_scene("croton", rig, seed=3)
        return cache[key]
    return render


def test_cli_imports_and_writes_a_rig_file(tmp_path):
    true = CASES["kalibr equidistant"][0]()
    [path] = write_kalibr(true, tmp_path)
    out = tmp_path / "rig.yaml"
    r = run_cli_subprocess("calibrate", "--from", "kalibr", path, "-o", out)
    assert r.returncode == 0, r.stderr
    got = load_rig(out)
    assert got.distortion_model == "equidistant" and got.world_unit == "m"
    assert np.percentile(projection_errors(true, got), 95) <= 0.5


def _misspell(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


@pytest.mark.parametrize("case, file_index, old, new, named", [
    ("ros-yaml plumb_bob", 0, "distortion_coefficients", "distortion_coefficents", "distortion_coefficents"),
    ("ros-ini ost.txt", 0, "rectification", "rectifcation", "rectifcation"),
    ("kalibr radtan", 0, "distortion_coeffs", "distortion_coefs", "distortion_coefs"),
    ("opencv yaml", 0, "D2:", "D_2:", "D_2"),
    ("opencv xml", 1, "R1", "Rl", "Rl"),
    ("middlebury", 0, "baseline", "baselin", "baselin"),
])
def test_misspelt_field_exits_2_with_one_line(case, file_index, old, new, named, tmp_path):
    make, fmt, writer = CASES[case]
    paths = writer(make(), tmp_path)
    _misspell(paths[file_index], old, new)
    r = run_cli_subprocess("calibrate", "--from", fmt, *paths, "-o", tmp_path / "rig.yaml")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and repr(named) in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "rig.yaml").exists()


def test_inconsistent_files_are_one_error_each(tmp_path):
    true = CASES["ros-yaml plumb_bob"][0]()
    left, right = write_ros_yaml(true, tmp_path)
    _misspell(right, "image_width: 640", "image_width: 800")
    with pytest.raises(CalibrationError, match="image sizes differ"):
        import_calibration("ros-yaml", [left, right])
    [camchain] = write_kalibr(CASES["kalibr radtan"][0](), tmp_path)
    import yaml

    doc = yaml.safe_load(camchain.read_text())
    doc["cam1"]["T_cn_cnm1"][0][0] = 1.2    # not a rotation any more
    camchain.write_text(yaml.dump(doc))
    with pytest.raises(CalibrationError, match="not a rotation"):
        import_calibration("kalibr", [camchain])
    sub = tmp_path / "cv"
    sub.mkdir()
    intr, extr = write_opencv(CASES["opencv yaml"][0](), sub, "yml")
    _rewrite_filestorage(extr, ("R", "T", "R1", "R2", "P1", "P2", "Q"),
                         T=lambda t: t * 1.1)  # R1 R2 P1 P2 no longer a rectification of R, T
    with pytest.raises(CalibrationError, match="not a rectification"):
        import_calibration("opencv", [intr, extr])
    with pytest.raises(CalibrationError, match="two files"):
        import_calibration("ros-yaml", [left])


def _rewrite_filestorage(path, keys, **change):
    """Rewrite a FileStorage file with only ``keys``, ``change[key](matrix)`` applied."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    fields = {k: fs.getNode(k).mat() for k in keys}
    fs.release()
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for k, v in fields.items():
        fs.write(k, change[k](v) if k in change else v)
    fs.release()


def test_opencv_file_without_size_needs_image_size(tmp_path):
    true = CASES["opencv yaml"][0]()
    intr, extr = write_opencv(true, tmp_path, "yml")
    _rewrite_filestorage(intr, ("M1", "D1", "M2", "D2"))   # the sample's intrinsics.yml: no size
    with pytest.raises(CalibrationError, match="--image-size"):
        import_calibration("opencv", [intr, extr])
    got = import_calibration("opencv", [intr, extr], image_size=(640, 480), unit="mm")
    assert np.percentile(projection_errors(true, got), 95) <= 0.5
