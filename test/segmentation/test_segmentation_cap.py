"""Segmentation at a capped processing size (issue 28: segment at a reduced scale, upsample the
mask): an HD frame costs what a 640x480 frame costs and gets the same mask."""
from __future__ import annotations

import cv2
import pytest

from canopy_stereo.segmentation.auto import VIDEO_SEEDER
from canopy_stereo.segmentation.propagate import DEFAULT_MAX_PIXELS, MaskPropagator, capped_scale

pytest.importorskip("mcap")


def test_capped_scale():
    assert capped_scale(0.25, (640, 480), max_pixels=DEFAULT_MAX_PIXELS) == 0.25
    assert capped_scale(0.25, (1280, 960), max_pixels=DEFAULT_MAX_PIXELS) == pytest.approx(0.125)
    s = capped_scale(0.25, (1280, 720), max_pixels=DEFAULT_MAX_PIXELS)
    assert 1280 * 720 * s * s == pytest.approx(DEFAULT_MAX_PIXELS)
    assert capped_scale(0.25, (1280, 960), max_pixels=0) == 0.25
    assert capped_scale(0.1, (1280, 960), max_pixels=DEFAULT_MAX_PIXELS) == 0.1  # already below the cap


@pytest.mark.slow
def test_hd_frame_is_segmented_at_the_capped_size_with_the_mask_of_its_640x480_version():
    """The bundled croton frame at 640x480 and upscaled to 1280x960: with the cap both are cut at
    160x120, so the HD mask is the 640x480 mask upsampled (IoU >= 0.97 after resizing), full
    cuts and propagated frames alike."""
    from test.segmentation.test_segmentation_propagate import bundled_lefts, iou

    frames = bundled_lefts("croton")[:3]
    small = MaskPropagator(settings=VIDEO_SEEDER, max_pixels=DEFAULT_MAX_PIXELS, recut_every=2)
    large = MaskPropagator(settings=VIDEO_SEEDER, max_pixels=DEFAULT_MAX_PIXELS, recut_every=2)
    for frame in frames:
        hd = cv2.resize(frame, (1280, 960), interpolation=cv2.INTER_LINEAR)
        mask_small, mask_large = small(frame), large(hd)
        assert mask_large.shape == (960, 1280)
        assert large.scale == pytest.approx(0.125) and large.propagate_scale == pytest.approx(0.125)
        up = cv2.resize(mask_small, (1280, 960), interpolation=cv2.INTER_NEAREST)
        assert iou(up, mask_large) >= 0.97
    assert (large.full_cuts, large.propagated) == (2, 1)
    # a frame of another size starts again with a full cut at its own capped scale
    large(frames[0])
    assert large.scale == 0.25 and large.full_cuts == 3
