"""The lens models (plumb_bob, rational_polynomial with thin prism, equidistant) against
OpenCV's own projectPoints / fisheye.projectPoints, and their inverses."""
import cv2
import numpy as np
import pytest

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.distortion import check_distortion, distort_pixels, distortion_is_identity, undistort_pixels
from canopy_stereo.geometry.rig import Rig

K = np.array([[520.0, 0.0, 322.5], [0.0, 518.0, 236.0], [0.0, 0.0, 1.0]])
P = np.hstack([K, np.zeros((3, 1))])
MODELS = {
    "plumb_bob": [-0.21, 0.08, 0.0011, -0.0007, -0.015],
    "rational_polynomial": [-0.30, 0.11, 0.0011, -0.0007, 0.02, 0.05, 0.01, 0.003],
    "thin prism": [-0.30, 0.11, 0.0011, -0.0007, 0.02, 0.05, 0.01, 0.003, 0.001, -0.0005, 0.0008, 0.0002],
    "equidistant": [0.05, -0.01, 0.003, -0.001],
}


def _points(n=2000, seed=0):
    rng = np.random.default_rng(seed)
    uv = rng.uniform([0, 0], [640, 480], (n, 2))
    return np.linalg.solve(K, np.c_[uv, np.ones(n)].T).T * rng.uniform(0.5, 3.0, n)[:, None]


@pytest.mark.parametrize("name", list(MODELS))
def test_distortion_equals_opencv_and_inverts(name):
    D = np.array(MODELS[name])
    model = "equidistant" if name == "equidistant" else None
    X = _points()
    ideal = (K @ (X / X[:, 2:]).T).T[:, :2]
    ours = distort_pixels(P, D, ideal, model=model)
    if model == "equidistant":
        cv = cv2.fisheye.projectPoints(X[None], np.zeros(3), np.zeros(3), K, D)[0][0]
    else:
        cv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, D)[0][:, 0]
    assert np.abs(ours - cv).max() < 1e-6
    back = undistort_pixels(P, D, ours, model=model)
    assert np.abs(back - ideal).max() < 1e-6


def test_zero_distortion_forms_and_checks():
    assert distortion_is_identity([1.0, 0, 0, 0, 0, 1.0, 0, 0])       # k1 == k4: the radial ratio is 1
    assert not distortion_is_identity([1.0, 0, 0, 0, 0, 0.5, 0, 0])
    xy = np.array([[10.0, 20.0], [600.0, 400.0]])
    assert np.array_equal(distort_pixels(P, [1.0, 0, 0, 0, 0, 1.0, 0, 0], xy), xy)
    with pytest.raises(RigError, match="equidistant"):
        check_distortion([0.1, 0, 0, 0, 0], "equidistant", "D")
    with pytest.raises(RigError, match="tilted"):
        check_distortion([0.1] * 14, None, "D")
    rig = Rig(P_left=P, P_right=K @ np.hstack([np.eye(3), [[-60.0], [0], [0]]]), image_size=(640, 480),
              D_left=MODELS["equidistant"], D_right=None, distortion_model="equidistant")
    assert rig.to_parameters()["distortion_model"] == "equidistant" and rig.D_right.size == 4
