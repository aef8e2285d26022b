import numpy as np
import pytest

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.camera import (
    camera_centre,
    compose_projection,
    decompose_projection,
    pixel_rays,
    point_depth,
    project,
    validate_projection,
)


def test_decomposition_recomposes_paper_matrices(paper_rig):
    for P in (paper_rig.P_left, paper_rig.P_right):
        cam = decompose_projection(P)
        assert np.linalg.det(cam.R) == pytest.approx(1.0, abs=1e-12)
        assert np.all(np.diag(cam.K) > 0) and cam.K[2, 2] == 1.0
        assert np.allclose(cam.R @ cam.R.T, np.eye(3), atol=1e-12)
        P2 = cam.P
        scale = P[2, 3] / P2[2, 3]
        assert np.allclose(P2 * scale, P, rtol=1e-9, atol=1e-6)


def test_paper_camera_centres_and_baseline(paper_rig):
    # values from decomposing the printed matrices; baseline about 29.6 mm
    assert np.allclose(camera_centre(paper_rig.P_left), [28.036, -65.023, -18.388], atol=1e-3)
    assert paper_rig.baseline == pytest.approx(29.628, abs=1e-3)


def test_sign_of_P_does_not_change_camera(paper_rig):
    a, b = decompose_projection(paper_rig.P_left), decompose_projection(-3.0 * paper_rig.P_left)
    assert np.allclose(a.K, b.K) and np.allclose(a.R, b.R) and np.allclose(a.C, b.C)


def test_rays_and_depth(rng):
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    ang = 0.3
    R = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    C = np.array([10.0, -5.0, 3.0])
    P = compose_projection(K, R, C)
    X = C + (R.T @ np.column_stack([rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50),
                                    rng.uniform(2, 9, 50)]).T).T
    depth = point_depth(P, X)
    assert np.all(depth > 0)
    rays = pixel_rays(-P, project(P, X))  # sign of P must not flip the rays
    expected = (X - C) / np.linalg.norm(X - C, axis=1, keepdims=True)
    assert np.allclose(rays, expected, atol=1e-12)


@pytest.mark.parametrize("bad, word", [
    (np.full((3, 4), np.nan), "non-finite"),
    (np.hstack([np.ones((3, 3)), np.ones((3, 1))]), "rank"),
    (np.ones((3, 3)), "3x4"),
])
def test_bad_matrices_are_rejected(bad, word):
    with pytest.raises(RigError, match=word):
        validate_projection(bad)
