import numpy as np
import pytest

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.calibration import calibrate_stereo_points, dlt_projection, gold_standard_projection
from canopy_stereo.geometry.camera import camera_centre, project
from canopy_stereo.io.correspondences import read_correspondences_csv


def paper_target(rig, rng, noise=0.2):
    """Corners of a vertical checkerboard at three depths, as in the paper's set-up."""
    X = np.array([[x, y, z] for z in (450.0, 600.0, 750.0)
                  for x in np.arange(-150, 251, 50.0) for y in np.arange(-200, 101, 50.0)])
    xl = project(rig.P_left, X) + rng.normal(0, noise, (len(X), 2))
    xr = project(rig.P_right, X) + rng.normal(0, noise, (len(X), 2))
    return X, xl, xr


def test_gold_standard_recovers_camera_centres_within_1mm(paper_rig, rng):
    X, xl, xr = paper_target(paper_rig, rng)
    cal = calibrate_stereo_points(X, xl, xr)
    assert np.linalg.norm(camera_centre(cal.P_left) - camera_centre(paper_rig.P_left)) < 1.0
    assert np.linalg.norm(camera_centre(cal.P_right) - camera_centre(paper_rig.P_right)) < 1.0
    # 0.2 px noise per coordinate -> about 0.28 px RMS
    assert 0.15 < cal.rms_left < 0.4 and 0.15 < cal.rms_right < 0.4
    # the Table-1 style check: depth is the worst axis, all small
    assert np.all(cal.check.mean_abs < [2.0, 2.0, 8.0])
    assert cal.check.mean_abs[2] > cal.check.mean_abs[0]


def test_lm_improves_on_dlt(paper_rig, rng):
    X, xl, _ = paper_target(paper_rig, rng, noise=0.5)
    from canopy_stereo.geometry.calibration import reprojection_errors

    P_dlt = dlt_projection(X, xl)
    P_gs, rms = gold_standard_projection(X, xl)
    rms_dlt = np.sqrt(np.mean(reprojection_errors(P_dlt, X, xl) ** 2))
    assert rms <= rms_dlt + 1e-9


def test_exact_data_gives_exact_matrix(paper_rig, rng):
    X, xl, _ = paper_target(paper_rig, rng, noise=0.0)
    P, rms = gold_standard_projection(X, xl)
    assert rms < 1e-6
    assert np.allclose(P / P[2, 3], paper_rig.P_left / paper_rig.P_left[2, 3], rtol=1e-6, atol=1e-6)


def test_too_few_points():
    with pytest.raises(CalibrationError, match="at least 6"):
        dlt_projection(np.random.rand(5, 3), np.random.rand(5, 2))


def test_coplanar_points_are_refused(paper_rig):
    X = np.array([[x, y, 600.0] for x in range(0, 200, 50) for y in range(0, 200, 50)])
    with pytest.raises(CalibrationError, match="coplanar"):
        dlt_projection(X, project(paper_rig.P_left, X))


def test_csv_reader_names_bad_lines(tmp_path):
    p = tmp_path / "pts.csv"
    p.write_text("X,Y,Z,u_left,v_left,u_right,v_right\n1,2,3,4,5,6,7\n1,2,x,4,5,6,7\n")
    with pytest.raises(CalibrationError, match="line 3"):
        read_correspondences_csv(p)
    p.write_text("X,Y,Z,u_left\n")
    with pytest.raises(CalibrationError, match="missing column"):
        read_correspondences_csv(p)
