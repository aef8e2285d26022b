"""The real Middlebury 2014 Plants pair: the automatic mask takes both plants (a jade plant and a
silver-leaved one), not the green watering can nor the two pots.

Hand-checked regions: test/data/plants_regions.json (polygons drawn on the image; see its
"about"). Coverage of a plant = fraction of its foliage pixels in its regions that the mask
takes; of an object = fraction of its region's pixels."""
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

REGIONS = Path(__file__).resolve().parents[1] / "data" / "plants_regions.json"


def region_masks(shape, grey):
    """name -> (kind, bool mask of the pixels that count) from the fixture."""
    fx = json.loads(REGIONS.read_text())
    out = {}
    for r in fx["regions"]:
        m = np.zeros(shape, np.uint8)
        for poly in r["polygons"]:
            cv2.fillPoly(m, [np.array(poly, np.int32)], 1)
        m = m.astype(bool)
        if r["kind"] == "foliage":
            m &= grey <= fx["wall_grey"]
        out[r["name"]] = (r["kind"], m)
    return out


def coverage(mask, shape, grey):
    return {name: float((mask & m).sum() / m.sum()) for name, (_, m) in region_masks(shape, grey).items()}


def check_coverage(cov):
    assert cov["jade"] >= 0.85 and cov["silver"] >= 0.85, cov
    assert cov["watering_can"] <= 0.05, cov
    assert cov["terracotta_pot"] <= 0.10 and cov["dark_green_pot"] <= 0.10, cov


@pytest.mark.slow
@pytest.mark.shared
def test_segment_auto_with_disparity_takes_plants_not_can_or_pots(shared_data, tmp_path, cli):
    folder = shared_data / "middlebury_MiddEval3_testQ" / "Plants"
    code, out, err = cli("disparity", folder / "im0.png", folder / "im1.png", "--disp-max", "80",
                         "-o", tmp_path / "D.pfm")
    assert code == 0, err
    code, out, err = cli("segment", folder / "im0.png", "--auto", "--disparity", tmp_path / "D.pfm",
                         "-o", tmp_path / "mask.png")
    assert code == 0, err
    assert "plants by shape" in out and (tmp_path / "mask_overlay.png").is_file()
    left = cv2.imread(str(folder / "im0.png"))
    mask = cv2.imread(str(tmp_path / "mask.png"), cv2.IMREAD_GRAYSCALE) > 0
    grey = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    check_coverage(coverage(mask, mask.shape, grey))
    # two plants, numbered left to right: the jade plant's taken foliage in plant 1's box, the
    # silver one's in plant 2's (the boxes overlap where the leaves touch: the centres tell)
    assert "2 plant(s)" in out, out
    boxes = {int(m[0]): tuple(int(v) for v in m[1:]) for m in
             re.findall(r"plant (\d+): \d+ pixels, box x (\d+)\.\.(\d+), y (\d+)\.\.(\d+)", out)}
    assert sorted(boxes) == [1, 2], out
    regions = region_masks(grey.shape, grey)
    for index, name in ((1, "jade"), (2, "silver")):
        x0, x1, y0, y1 = boxes[index]
        rows, cols = np.nonzero(regions[name][1] & mask)
        inside = (cols >= x0) & (cols <= x1) & (rows >= y0) & (rows <= y1)
        assert inside.mean() >= 0.95, (name, boxes)
    centre = {k: (b[0] + b[1]) / 2 for k, b in boxes.items()}
    assert centre[1] < centre[2]


@pytest.mark.slow
@pytest.mark.shared
def test_segment_plants_on_the_organized_cloud_of_the_pair(shared_data):
    """The cloud path (``points=``, as ``reconstruct --auto-mask`` calls it): the pair's cloud
    triangulated with its own calibration, Z = f B / (d + doffs); camera given or estimated."""
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.io.middlebury import load_middlebury_2014
    from canopy_stereo.segmentation import segment_plants

    scene = load_middlebury_2014(shared_data / "middlebury_MiddEval3_testQ" / "Plants")
    grey = cv2.cvtColor(scene["left"], cv2.COLOR_BGR2GRAY)
    d = compute_disparity(grey, cv2.cvtColor(scene["right"], cv2.COLOR_BGR2GRAY), matcher="elas",
                          disp_min=0, disp_max=80).astype(float)
    d[d < 0] = np.nan
    calib = scene["calib"]
    K = calib["cam0"]
    f, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    Z = f * calib["baseline"] / (d + calib["doffs"])
    v, u = np.mgrid[0:d.shape[0], 0:d.shape[1]]
    cloud = np.dstack([(u - cx) * Z / f, (v - cy) * Z / f, Z])
    for camera in (np.hstack([K, np.zeros((3, 1))]), None):
        seg = segment_plants(scene["left"], points=cloud, camera=camera)
        check_coverage(coverage(seg.mask > 0, grey.shape, grey))
        check_two_plants(seg, grey)


def check_two_plants(seg, grey):
    """The two plants' leaves touch in the image: they are told apart by the pots they grow from
    (jade plant 1, silver plant 2, left to right), and the pieces of the table's dark rim at the
    image's sides are not plants."""
    assert seg.n_plants == 2, seg.plants
    regions = region_masks(grey.shape, grey)
    for index, name in ((1, "jade"), (2, "silver")):
        taken = regions[name][1] & (seg.mask > 0)
        assert (seg.instances[taken] == index).mean() >= 0.9, name


@pytest.mark.slow
@pytest.mark.shared
def test_reconstruct_auto_mask_takes_plants_not_can_or_pots(shared_data, tmp_path, cli):
    """The mask ``reconstruct --auto-mask`` (and ``--measure``) uses: the pair reconstructed with the
    bundled rig (the pair is rectified already and kept: no cut, no resampling) and
    :func:`~canopy_stereo.measure.plant.automatic_plant_mask` on its cloud."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.measure.plant import automatic_plant_mask
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    folder = shared_data / "middlebury_MiddEval3_testQ" / "Plants"
    rig_path = Path(__file__).resolve().parents[2] / "config" / "plants_rig.yaml"
    rig = load_rig(rig_path)
    left, right = cv2.imread(str(folder / "im0.png")), cv2.imread(str(folder / "im1.png"))
    rec = reconstruct_pair(left, right, rig)
    assert rec.rectification.doffs == pytest.approx(-85.019) and rec.disp_range == (0, 81)
    mask = automatic_plant_mask(left, rec.organized, rig)
    grey = cv2.cvtColor(left, cv2.COLOR_BGR2GRAY)
    check_coverage(coverage(mask, mask.shape, grey))
    code, out, err = cli("reconstruct", folder / "im0.png", folder / "im1.png", "--rig", rig_path,
                         "-o", tmp_path / "plants.ply", "--auto-mask")
    assert code == 0, err
    assert f"plant: automatic plant mask, {mask.mean() * 100:.1f} % of the left image" in out
    assert (tmp_path / "plants_overlay.png").is_file()
