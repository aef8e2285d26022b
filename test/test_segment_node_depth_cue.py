"""segment_node's depth cue: the one plant seeder (:class:`SeederSettings`) with the disparity,
in a process of its own, fed by a foreign publisher."""
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.ros import convert  # noqa: E402
from ros_harness import Probe, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros]

T0 = 1_750_000_000_000_000_000


def _red_plant_scene(seed=3, size=(240, 320)):
    """Red leaves (which the excess-green index does not see) on textured brown soil, their
    disparity (leaves 40 px, soil 12 px, noisy; unknown rows at the top) and the truth mask."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.empty((h, w, 3), np.float64)
    img[:] = (60, 90, 130)  # brown soil (BGR)
    img += cv2.GaussianBlur(rng.normal(0, 25, (h, w, 3)), (0, 0), 2)
    truth = np.zeros((h, w), np.uint8)
    cv2.ellipse(truth, (110, 120), (70, 35), 30, 0, 360, 1, -1)
    cv2.ellipse(truth, (220, 110), (55, 30), -40, 0, 360, 1, -1)
    leaf = np.asarray((50, 60, 200), np.float64) * (0.8 + 0.4 * rng.random((h, w, 1)))
    img = np.clip(np.where(truth[..., None] > 0, leaf, img), 0, 255).astype(np.uint8)
    truth = truth.astype(bool)
    disparity = np.where(truth, 40.0, 12.0) + rng.normal(0, 0.5, truth.shape)
    disparity[:4] = -1.0
    return img, disparity.astype(np.float32), truth


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


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
    img, disparity, truth = _red_plant_scene()
    # the video preset with the depth cue separates what colour cannot
    no_depth = plant_mask(img, VIDEO_SEEDER.replace(colour_cue="exg")) > 0
    with_depth = plant_mask(img, VIDEO_SEEDER.replace(depth_cue=True, colour_cue="none"),
                            disparity=disparity) > 0
    assert _iou(with_depth, truth) > 0.9 > _iou(no_depth, truth) + 0.3
    with pytest.raises(ValueError, match="depth_cue is off"):
        plant_mask(img, VIDEO_SEEDER, disparity=disparity)


def test_segment_node_process_uses_the_disparity_cue(ros_processes):
    """``segment_node --ros-args -p depth_cue:=true -p auto_init:=none`` in its own process:
    a mask waits for the disparity of its image and follows the disparity, not the colour."""
    ros_processes.start("segment_node", params={"depth_cue": True, "auto_init": "none", "scale": 0.5})
    probe = Probe(ros_processes.domain_id)
    try:
        pub_img = probe.publisher(Image, "left/image_rect_color")
        pub_disp = probe.publisher(DisparityImage, "disparity")
        masks = probe.subscribe(Image, "left/mask")
        assert wait_for(lambda: pub_img.get_subscription_count() >= 1 and pub_disp.get_subscription_count() >= 1
                        and masks.subscription.get_publisher_count() >= 1, 60.0,
                        group=ros_processes), ros_processes.logs()
        img, disparity, truth = _red_plant_scene()
        # an image alone is not segmented: its disparity has not come
        pub_img.publish(convert.image_to_msg(img, "bgr8", T0, "left_rect"))
        time.sleep(1.5)
        assert len(masks) == 0, ros_processes.logs()
        # doffs 5: message disparities are u_left - u_right - 5 (the node measures from the range start)
        pub_disp.publish(convert.disparity_to_msg(disparity, 500.0, 0.06, 0, 64, stamp_ns=T0,
                                                  frame_id="left_rect", doffs=5.0))
        assert wait_for(lambda: len(masks) == 1, 60.0, group=ros_processes), ros_processes.logs()
        # the next frame: disparity first, then the image
        pub_disp.publish(convert.disparity_to_msg(disparity, 500.0, 0.06, 0, 64, stamp_ns=T0 + 1,
                                                  frame_id="left_rect", doffs=5.0))
        pub_img.publish(convert.image_to_msg(img, "bgr8", T0 + 1, "left_rect"))
        assert wait_for(lambda: len(masks) == 2, 60.0, group=ros_processes), ros_processes.logs()
        assert masks.stamps() == [T0, T0 + 1]
        for _, _, data in masks.items:
            msg = deserialize_message(data, Image)
            mask = convert.msg_to_image(msg, ("mono8",)) > 0
            assert msg.header.frame_id == "left_rect" and mask.shape == truth.shape
            assert _iou(mask, truth) > 0.9, _iou(mask, truth)
    finally:
        probe.close()
