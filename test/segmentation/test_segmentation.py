"""Plant segmentation: indices, Otsu, GrabCut, automatic masks, CLI, bad input."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.segmentation import (
    auto_plant_mask,
    excess_green,
    excess_green_minus_red,
    grabcut_mask,
    grabcut_rect,
    otsu_threshold,
    plant_seed,
    read_leaf_ids,
    read_mask,
    vegetation_index,
    write_leaf_ids,
    write_mask,
)
from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD
from test.support.segmentation import blob_scene, iou


def test_indices_on_pure_colours():
    px = np.array([[[0, 200, 0], [0, 0, 200], [100, 100, 100], [0, 0, 0]]], np.uint8)  # BGR
    exg = excess_green(px)[0]
    assert exg[0] == pytest.approx(2.0) and exg[1] == pytest.approx(-1.0)
    assert exg[2] == pytest.approx(0.0) and exg[3] == pytest.approx(0.0)
    exgr = excess_green_minus_red(px)[0]
    assert exgr[0] == pytest.approx(3.0) and exgr[1] == pytest.approx(-2.4) and exgr[2] == pytest.approx(-0.4 / 3)
    with pytest.raises(ImageError, match="unknown vegetation index"):
        vegetation_index(px, "ndvi")
    with pytest.raises(ImageError, match="colour"):
        excess_green(np.zeros((4, 4), np.uint8))


def test_otsu_threshold_splits_two_modes(rng):
    v = np.concatenate([rng.normal(0.0, 0.05, 5000), rng.normal(1.0, 0.05, 2000), [1e9, -1e9]])
    t = otsu_threshold(v)
    assert 0.3 < t < 0.7
    assert otsu_threshold(np.full(10, 3.0)) == 3.0


def test_grabcut_rect_finds_the_plant():
    img, truth = blob_scene()
    mask = grabcut_rect(img, (30, 40, 270, 160))
    assert mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
    assert iou(mask, truth) > 0.9


def test_grabcut_mask_refines_a_rough_mask():
    img, truth = blob_scene()
    rough = cv2.dilate(truth.astype(np.uint8) * 255, np.ones((15, 15), np.uint8))
    assert iou(rough, truth) < 0.8
    refined = grabcut_mask(img, rough, margin_px=10)
    assert iou(refined, truth) > 0.9
    # explicit GrabCut labels
    labels = np.full(truth.shape, GC_BGD, np.uint8)
    labels[cv2.dilate(truth.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0] = GC_PR_FGD
    labels[cv2.erode(truth.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0] = GC_FGD
    assert iou(grabcut_mask(img, labels), truth) > 0.9


def test_auto_mask_green_plant_by_colour():
    img, truth = blob_scene()
    mask = auto_plant_mask(img)
    assert iou(mask, truth) > 0.95


def test_auto_mask_red_plant_needs_the_depth_cue():
    img, truth = blob_scene(leaf_bgr=(50, 60, 200))  # red leaves: ExG does not see them
    assert iou(auto_plant_mask(img), truth) < 0.5
    disparity = np.where(truth, 40.0, 12.0) + np.random.default_rng(1).normal(0, 0.5, truth.shape)
    disparity[:5] = -1.0  # unknown rows
    mask = auto_plant_mask(img, disparity=disparity, index="none")
    assert iou(mask, truth) > 0.95
    depth = np.where(truth, 500.0, 1200.0)
    assert iou(auto_plant_mask(img, depth=depth, index="none"), truth) > 0.95
    # an explicit range instead of Otsu
    assert iou(auto_plant_mask(img, disparity=disparity, index="none", disparity_range=(30, 50)), truth) > 0.95


def test_seed_labels_combine_colour_and_depth():
    img, truth = blob_scene()
    depth = np.where(truth, 500.0, 1200.0)
    depth[:, :160] = 500.0  # a near, non-green thing on the left (a pot)
    seed = plant_seed(img, depth=depth)
    assert set(np.unique(seed)) <= {GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD}
    near = (depth < 600).astype(np.uint8)
    far_from_edges = ~cv2.dilate(near, np.ones((11, 11), np.uint8)).astype(bool)
    assert np.all(seed[far_from_edges] == GC_BGD)  # far = sure background (edges: probable)
    near_not_green = (~truth) & (depth < 600)
    assert np.mean((seed[near_not_green] == GC_PR_BGD) | (seed[near_not_green] == GC_BGD)) > 0.95
    assert iou((seed == GC_FGD) | (seed == GC_PR_FGD), truth) > 0.9


def test_segmentation_bad_input():
    img, truth = blob_scene()
    with pytest.raises(ImageError, match="covers the whole image"):
        grabcut_rect(img, (0, 0, img.shape[1], img.shape[0]))
    with pytest.raises(ImageError, match="outside"):
        grabcut_rect(img, (1000, 1000, 50, 50))
    with pytest.raises(ImageError, match="positive width"):
        grabcut_rect(img, (10, 10, 0, 5))
    with pytest.raises(ImageError, match="no plant pixel"):
        grabcut_mask(img, np.zeros(truth.shape, np.uint8))
    with pytest.raises(ImageError, match="no background pixel"):
        grabcut_mask(img, np.full(truth.shape, 255, np.uint8))
    with pytest.raises(ImageError, match="mask is 10x10 but the image is 320x240"):
        grabcut_mask(img, np.ones((10, 10), bool))
    with pytest.raises(ImageError, match="registered to the image"):
        auto_plant_mask(img, disparity=np.ones((10, 10)))
    with pytest.raises(ImageError, match="no valid value"):
        auto_plant_mask(img, disparity=np.full(truth.shape, -1.0), index="none")
    with pytest.raises(ImageError, match="either a disparity or a depth"):
        plant_seed(img, disparity=np.ones(truth.shape), depth=np.ones(truth.shape))
    with pytest.raises(ImageError, match="no cue"):
        plant_seed(img, index="none")
    assert issubclass(ImageError, CanopyStereoError)


def test_seeder_presets_and_node_parameters_come_from_one_settings_object():
    from canopy_stereo.segmentation import IMAGE_SEEDER, VIDEO_SEEDER, SeederSettings, plant_mask
    from canopy_stereo.segmentation.auto import decode_setting, encode_setting, seeder_fields

    assert (IMAGE_SEEDER.colour_cue, IMAGE_SEEDER.depth_cue, IMAGE_SEEDER.scale) == ("exg", True, 1.0)
    assert (VIDEO_SEEDER.colour_cue, VIDEO_SEEDER.depth_cue, VIDEO_SEEDER.scale) == ("saturation", False, 0.25)
    names = {f["name"]: f for f in seeder_fields(VIDEO_SEEDER)}
    assert {"auto_init", "depth_cue", "iterations", "scale", "sure_margin", "edge_px", "colour_model",
            "refine", "min_region"} == set(names)
    assert names["scale"]["minimum"] == 0.01 and names["scale"]["maximum"] == 1.0
    for f in seeder_fields(VIDEO_SEEDER):  # the encoding round-trips every default
        assert decode_setting(f["field"], f["default"]) == getattr(VIDEO_SEEDER, f["field"])
        assert encode_setting(f["field"], getattr(VIDEO_SEEDER, f["field"])) == f["default"]
    with pytest.raises(ValueError, match="scale"):
        SeederSettings(scale=0.0)
    img, truth = blob_scene(leaf_bgr=(50, 60, 200))  # red leaves: excess green does not see them
    disparity = np.where(truth, 40.0, 12.0) + np.random.default_rng(1).normal(0, 0.5, truth.shape)
    # the video preset with the depth cue separates what colour cannot
    no_depth = plant_mask(img, VIDEO_SEEDER.replace(colour_cue="exg")) > 0
    with_depth = plant_mask(img, VIDEO_SEEDER.replace(depth_cue=True, colour_cue="none"),
                            disparity=disparity) > 0
    assert iou(with_depth, truth) > 0.9 > iou(no_depth, truth) + 0.3
    with pytest.raises(ValueError, match="depth_cue is off"):
        plant_mask(img, VIDEO_SEEDER, disparity=disparity)


def test_mask_and_id_image_io(tmp_path):
    m = np.zeros((20, 30), bool)
    m[5:10, 5:25] = True
    write_mask(tmp_path / "m.png", m)
    assert np.array_equal(read_mask(tmp_path / "m.png"), m)
    ids = np.zeros((20, 30), np.int64)
    ids[2:5, 2:5] = 3
    ids[10:15, 10:20] = 700  # needs 16 bits
    write_leaf_ids(tmp_path / "ids.png", ids)
    assert np.array_equal(read_leaf_ids(tmp_path / "ids.png"), ids)
    colour = np.zeros((20, 30, 3), np.uint8)
    colour[2:5, 2:5] = (0, 0, 255)  # BGR red -> id 0xFF0000
    cv2.imwrite(str(tmp_path / "c.png"), colour)
    got = read_leaf_ids(tmp_path / "c.png")
    assert got[3, 3] == 0xFF0000 and got[0, 0] == 0
    with pytest.raises(ImageError, match="not found"):
        read_mask(tmp_path / "missing.png")
    (tmp_path / "bad.png").write_text("not an image")
    with pytest.raises(ImageError, match="cannot read"):
        read_leaf_ids(tmp_path / "bad.png")
