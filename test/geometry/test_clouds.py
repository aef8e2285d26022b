"""One check of point arrays and organized clouds (geometry.clouds.check_cloud), used by
every reader, writer and consumer of clouds: they refuse the same arrays in the same words."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.geometry.clouds import check_cloud, check_on_grid


def test_check_cloud_accepts_clouds_and_names_what_is_wrong():
    org = check_cloud([[[1, 2, 3], [4, 5, 6]]])
    assert org.dtype == np.float64 and org.shape == (1, 2, 3)
    pts = check_cloud(np.zeros((4, 3), np.int16), organized=False, dtype=np.float32)
    assert pts.dtype == np.float32 and pts.shape == (4, 3)
    assert check_cloud(np.zeros((2, 2, 3)), organized=None).shape == (2, 2, 3)
    assert check_cloud(np.full((3, 3), np.nan), organized=None).shape == (3, 3)   # NaN = no point
    with pytest.raises(CanopyStereoError, match=r"organized cloud must be an \(H, W, 3\) array .*, got shape \(4, 3\)"):
        check_cloud(np.zeros((4, 3)))
    with pytest.raises(CanopyStereoError, match=r"points must be an \(N, 3\) array .*, got shape \(2, 2, 3\)"):
        check_cloud(np.zeros((2, 2, 3)), organized=False, name="points")
    with pytest.raises(CanopyStereoError, match=r"must be an \(N, 3\) or \(H, W, 3\) array, got shape \(5, 2\)"):
        check_cloud(np.zeros((5, 2)), organized=None)
    with pytest.raises(CanopyStereoError, match=r"must be an \(H, W, 3\) array .*, got shape \(1, 5, 3\)"):
        check_cloud(np.zeros((1, 5, 3)), min_size=2)
    with pytest.raises(CanopyStereoError, match="must hold real coordinates"):
        check_cloud(np.zeros((2, 2, 3), complex))
    with pytest.raises(CanopyStereoError, match="is not numeric"):
        check_cloud([["a", "b", "c"]], organized=None)
    with pytest.raises(CanopyStereoError, match="is not numeric"):
        check_cloud([[1, 2, 3], [4, 5]], organized=None)
    with pytest.raises(ImageError):
        check_cloud(np.zeros(3), organized=None, error=ImageError)
    check_on_grid(np.zeros((4, 5), bool), np.zeros((4, 5, 3)), "mask")
    with pytest.raises(CanopyStereoError,
                       match=r"^mask is 5x4 but the organized cloud is 6x4 \(draw it on the left\)$"):
        check_on_grid(np.zeros((4, 5), bool), np.zeros((4, 6, 3)), "mask", hint="draw it on the left")


def test_every_consumer_refuses_a_flat_point_list_with_the_same_words(tmp_path):
    from canopy_stereo.fusion.views import View
    from canopy_stereo.io.ply import write_ply
    from canopy_stereo.measure import measure_leaf, measure_points, measure_scene, separate_leaves

    bad = np.zeros((6, 2))
    words = r"must be an (\(H, W, 3\) array .*|\(N, 3\) or \(H, W, 3\) array), got shape \(6, 2\)"
    calls = [lambda: write_ply(tmp_path / "c.ply", bad),
             lambda: measure_points(bad),
             lambda: measure_scene(bad),
             lambda: measure_leaf(bad, np.ones((6, 2), bool)),
             lambda: separate_leaves(bad, np.ones((6, 2), bool)),
             lambda: View("v", bad, None, "mm")]
    for call in calls:
        with pytest.raises(CanopyStereoError, match=words):
            call()
    assert not (tmp_path / "c.ply").exists()


def test_the_ros_converter_uses_the_same_check():
    convert = pytest.importorskip("canopy_stereo.ros.convert")
    with pytest.raises(ImageError, match=r"points must be an \(N, 3\) or \(H, W, 3\) array, got shape \(6, 2\)"):
        convert.points_to_cloud2(np.zeros((6, 2)))
    msg = convert.points_to_cloud2(np.arange(12, dtype=np.float64).reshape(4, 3))
    assert msg.width * msg.height == 4
