"""The one synthetic stereo-pair generator (canopy_stereo.sim.stereo_pair): every texture
renders the plane it is given."""
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.sim.stereo_pair import TEXTURES, synthetic_pair


@pytest.mark.parametrize("texture", TEXTURES)
def test_right_image_shows_the_left_pixel_at_u_minus_d(texture):
    left, right, d = synthetic_pair(120, 80, plane=(0, 0, 7), texture=texture, seed=3)
    assert left.dtype == right.dtype == np.uint8 and left.shape == right.shape == (80, 120)
    assert np.all(np.isnan(d[:, :7])) and np.all(d[:, 7:] == 7)
    # an integer shift is exact: right[v, u - 7] == left[v, u]
    assert np.array_equal(right[:, :-7], left[:, 7:])


def test_slanted_plane_subpixel_disparity_and_options():
    left, right, d = synthetic_pair(160, 100, plane=(0.05, 0.02, 6.0), seed=1)
    v, u = 50, 100
    assert d[v, u] == pytest.approx(0.05 * u + 0.02 * v + 6.0, abs=1e-5)
    # the right image sees the left pixel u at x = u - d: compare by linear interpolation
    x = u - d[v, u]
    x0 = int(np.floor(x))
    r = (1 - (x - x0)) * float(right[v, x0]) + (x - x0) * float(right[v, x0 + 1])
    assert abs(r - float(left[v, u])) < 6
    colour = synthetic_pair(64, 48, plane=(0, 0, 4), texture="blocks", colour=True)[0]
    assert colour.shape == (48, 64, 3)
    noisy = synthetic_pair(64, 48, texture="two_scale", noise=2.0, outside=None)
    assert noisy[2].dtype == np.float64 and not np.isnan(noisy[2]).any()
    with pytest.raises(CanopyStereoError, match="texture"):
        synthetic_pair(64, 48, texture="checker")
    with pytest.raises(CanopyStereoError, match="integer"):
        synthetic_pair(64, 48, plane=(0, 0, 2.5), texture="blocks")
    with pytest.raises(CanopyStereoError, match="slope"):
        synthetic_pair(64, 48, plane=(1.0, 0, 2))
