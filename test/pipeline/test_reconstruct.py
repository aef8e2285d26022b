import numpy as np
import pytest

from canopy_stereo.errors import ImageError
from canopy_stereo.pipeline.reconstruct import reconstruct_pair


@pytest.mark.parametrize("scene", ["Adirondack", "Motorcycle"])
def test_middlebury_2014_depths_within_2_percent(shared_data, scene):
    from canopy_stereo.io.middlebury import load_middlebury_2014

    s = load_middlebury_2014(shared_data / "middlebury_MiddEval3_trainingQ" / scene)
    c = s["calib"]
    rec = reconstruct_pair(s["left"], s["right"], s["rig"], matcher="sgbm")
    z_true = c["baseline"] * c["cam0"][0, 0] / (s["disp"] + c["doffs"])
    z = rec.organized[:, :, 2]
    truth = s["nonocc"] & np.isfinite(z_true)
    both = truth & np.isfinite(z)
    rel = np.abs(z[both] - z_true[both]) / z_true[both]
    assert np.median(rel) < 0.02
    assert both.sum() / truth.sum() > 0.6
    # points are in the left camera frame in mm: x, y agree with the pinhole model too
    vv, uu = np.nonzero(both)
    f, cx, cy = c["cam0"][0, 0], c["cam0"][0, 2], c["cam0"][1, 2]
    X = rec.organized[vv, uu]
    assert np.allclose(X[:, 0] / X[:, 2] * f + cx, uu, atol=1e-3)
    assert np.allclose(X[:, 1] / X[:, 2] * f + cy, vv, atol=1e-3)


def test_mask_restricts_points(shared_data):
    from canopy_stereo.io.middlebury import load_middlebury_2014

    s = load_middlebury_2014(shared_data / "middlebury_MiddEval3_trainingQ" / "ArtL")
    mask = np.zeros(s["left"].shape[:2], np.uint8)
    mask[100:200, 100:250] = 255
    rec = reconstruct_pair(s["left"], s["right"], s["rig"], mask=mask)
    assert np.all(mask[rec.pixels[:, 1], rec.pixels[:, 0]] > 0)
    # exactly the unmasked reconstruction's points inside the mask
    full = reconstruct_pair(s["left"], s["right"], s["rig"])
    inside = mask[full.pixels[:, 1], full.pixels[:, 0]] > 0
    assert len(rec.points) == inside.sum() == np.sum(np.all(np.isfinite(full.organized), -1) & (mask > 0))
    order, order_full = np.lexsort(rec.pixels.T), np.lexsort(full.pixels[inside].T)
    np.testing.assert_array_equal(rec.pixels[order], full.pixels[inside][order_full])
    np.testing.assert_allclose(rec.points[order], full.points[inside][order_full])
    with pytest.raises(ImageError, match="mask"):
        reconstruct_pair(s["left"], s["right"], s["rig"], mask=np.zeros((10, 10), np.uint8))


def test_wrong_image_size_for_rig(paper_rig):
    img = np.zeros((100, 120, 3), np.uint8)
    with pytest.raises(ImageError, match="rig expects 640x480"):
        reconstruct_pair(img, img, paper_rig)


@pytest.mark.slow
def test_hartley_rectification_still_gives_metric_points(paper_rig):
    """The paper's route: projective rectification from quasi-dense matches, matches mapped
    back through the inverse homographies, triangulated with the world-frame P matrices."""
    from canopy_stereo.sim import render_scene

    sim = render_scene("croton", paper_rig, seed=1)
    rec = reconstruct_pair(sim.left, sim.right, paper_rig, method="hartley", matcher="sgbm")
    assert rec.rectification.method == "hartley"
    leaf = sim.leaf_ids_left > 0
    truth, est = sim.xyz_left, rec.organized
    both = leaf & np.all(np.isfinite(truth), axis=2) & np.all(np.isfinite(est), axis=2)
    assert both.sum() > 0.6 * leaf.sum()
    from canopy_stereo.geometry.camera import camera_centre

    dist = np.linalg.norm(truth[both] - camera_centre(paper_rig.P_left), axis=1)
    err = np.linalg.norm(est[both] - truth[both], axis=1)
    assert np.median(err / dist) < 0.01
