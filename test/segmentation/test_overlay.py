"""The overlay picture: the mask's outline over the image, one colour per plant."""
import numpy as np
import pytest

from canopy_stereo.errors import ImageError
from canopy_stereo.segmentation import mask_overlay
from canopy_stereo.segmentation.overlay import OUTLINE_COLOURS


def test_outline_follows_the_mask_and_dims_the_rest():
    img = np.full((60, 80, 3), 200, np.uint8)
    mask = np.zeros((60, 80), np.uint8)
    mask[20:40, 10:30] = 255
    out = mask_overlay(img, mask, thickness=1)
    assert out.shape == img.shape and out.dtype == np.uint8
    assert np.all(img == 200)  # the input is not drawn on
    assert tuple(out[20, 20]) == OUTLINE_COLOURS[0]  # top edge of the square
    assert tuple(out[30, 20]) == (200, 200, 200)  # inside: untouched
    assert tuple(out[5, 60]) == (120, 120, 120)  # outside: dimmed


def test_each_plant_gets_its_own_colour():
    img = np.full((60, 120, 3), 100, np.uint8)
    inst = np.zeros((60, 120), np.int32)
    inst[20:40, 10:30] = 1
    inst[20:40, 70:90] = 2
    out = mask_overlay(img, inst > 0, instances=inst, thickness=1, label=False)
    assert tuple(out[30, 10]) == OUTLINE_COLOURS[0] and tuple(out[30, 70]) == OUTLINE_COLOURS[1]


def test_overlay_rejects_a_mask_of_another_size():
    with pytest.raises(ImageError, match="mask is 10x5"):
        mask_overlay(np.zeros((6, 8, 3), np.uint8), np.zeros((5, 10), np.uint8))
