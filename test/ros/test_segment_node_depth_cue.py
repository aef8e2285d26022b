"""segment_node's depth cue: the one plant seeder (SeederSettings) with the disparity, in a
process of its own, fed by a foreign publisher."""
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
from test.support.ros_harness import Probe, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros]

T0 = 1_750_000_000_000_000_000


def _red_plant_scene(seed=3, size=(240, 320)):
    """A red plant (which excess green does not see) on noisy brown soil, its disparity
    (plant 40 px, soil 12 px, noisy; unknown rows at the top) and the truth mask."""
    rng = np.random.default_rng(seed)
    truth = np.zeros(size, np.uint8)
    cv2.ellipse(truth, (150, 120), (80, 50), 20, 0, 360, 1, -1)
    truth = truth.astype(bool)
    colours = np.where(truth[..., None], (50.0, 60.0, 200.0), (60.0, 90.0, 130.0))
    img = np.clip(colours + rng.normal(0, 15, size + (3,)), 0, 255).astype(np.uint8)
    disparity = np.where(truth, 40.0, 12.0) + rng.normal(0, 0.5, size)
    disparity[:4] = -1.0
    return img, disparity.astype(np.float32), truth


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def _segment_node_and_probe(ros_processes, params):
    """``segment_node`` with ``params`` in its own process and a probe matched with it:
    ``(probe, image publisher, disparity publisher, mask subscription)``."""
    ros_processes.start("segment_node", params=params)
    probe = Probe(ros_processes.domain_id)
    pub_img = probe.publisher(Image, "left/image_rect_color")
    pub_disp = probe.publisher(DisparityImage, "disparity")
    masks = probe.subscribe(Image, "left/mask")
    try:
        assert wait_for(lambda: pub_img.get_subscription_count() >= 1 and pub_disp.get_subscription_count() >= 1
                        and masks.subscription.get_publisher_count() >= 1, 60.0,
                        group=ros_processes), ros_processes.logs()
    except BaseException:
        probe.close()
        raise
    return probe, pub_img, pub_disp, masks


@pytest.mark.slow
def test_segment_node_process_uses_the_disparity_cue(ros_processes):
    """``segment_node --ros-args -p depth_cue:=true -p auto_init:=none`` in its own process:
    a mask waits for the disparity of its image and follows the disparity, not the colour."""
    probe, pub_img, pub_disp, masks = _segment_node_and_probe(
        ros_processes, {"depth_cue": True, "auto_init": "none", "scale": 0.5})
    try:
        img, disparity, truth = _red_plant_scene()
        # an image alone is not segmented: its disparity has not come
        pub_img.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0, frame_id="left_rect"))
        time.sleep(1.5)
        assert len(masks) == 0, ros_processes.logs()
        # doffs 5: message disparities are u_left - u_right - 5 (the node measures from the range start)
        pub_disp.publish(convert.disparity_to_msg(disparity, 500.0, 0.06, 0, 64, stamp_ns=T0,
                                                  frame_id="left_rect", doffs=5.0))
        assert wait_for(lambda: len(masks) == 1, 60.0, group=ros_processes), ros_processes.logs()
        # the next frame: disparity first, then the image
        pub_disp.publish(convert.disparity_to_msg(disparity, 500.0, 0.06, 0, 64, stamp_ns=T0 + 1,
                                                  frame_id="left_rect", doffs=5.0))
        pub_img.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0 + 1, frame_id="left_rect"))
        assert wait_for(lambda: len(masks) == 2, 60.0, group=ros_processes), ros_processes.logs()
        assert masks.stamps() == [T0, T0 + 1]
        for _, _, data in masks.items:
            msg = deserialize_message(data, Image)
            mask = convert.msg_to_image(msg, ("mono8",)) > 0
            assert msg.header.frame_id == "left_rect" and mask.shape == truth.shape
            assert _iou(mask, truth) > 0.9, _iou(mask, truth)
    finally:
        probe.close()


@pytest.mark.slow
def test_graph_masks_follow_the_disparity_with_the_depth_cue():
    """The in-process graph (GraphOptions.segment_depth_cue, canopy_graph --segment-depth-cue)
    on the croton bag: every frame gets a mask, and the masked pixels are the near ones."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_bag, bundled_rig
    from canopy_stereo.ros.graph import GraphOptions
    from canopy_stereo.ros.runner import run_bag

    result = run_bag(bundled_bag("croton"), load_rig(bundled_rig("croton")), rate=0,
                     keep=("disparity", "left/mask"),
                     options=GraphOptions(use_mask=True, segment_depth_cue=True, parameter_services=False))
    assert result.frames_in == result.frames_out == 4
    masks = dict(result.outputs["left/mask"])
    disparities = dict(result.outputs["disparity"])
    assert len(masks) == 4 and set(masks) == set(disparities)
    for stamp, data in masks.items():
        mask = convert.msg_to_image(deserialize_message(data, Image), ("mono8",)) > 0
        d = convert.msg_to_disparity(deserialize_message(disparities[stamp], DisparityImage)).disparity
        valid = np.isfinite(d)
        assert 0.05 < mask.mean() < 0.95
        near, far = np.median(d[mask & valid]), np.median(d[~mask & valid])
        assert near > far + 3.0, (near, far)  # the croton stands about 0.3 m before its backdrop


@pytest.mark.slow
def test_segment_node_follow_disparity_segments_only_the_matched_frames(ros_processes):
    """``follow_disparity:=true`` (the masked graph's setting): three images, disparities for
    the first and the third only (the matcher skipped the second): two masks, for those stamps,
    found by colour as without it (the disparity's values are not used)."""
    probe, pub_img, pub_disp, masks = _segment_node_and_probe(ros_processes, {"follow_disparity": True, "scale": 0.5})
    try:
        img, disparity, truth = _red_plant_scene()
        for k in range(3):
            pub_img.publish(convert.image_to_msg(img, "bgr8", stamp_ns=T0 + k, frame_id="left_rect"))
        time.sleep(1.0)
        assert len(masks) == 0, ros_processes.logs()  # no disparity yet: nothing segmented
        flat = np.full_like(disparity, 20.0)  # says nothing about the plant: the colour finds it
        for k in (0, 2):
            pub_disp.publish(convert.disparity_to_msg(flat, 500.0, 0.06, 0, 64, stamp_ns=T0 + k,
                                                      frame_id="left_rect"))
        assert wait_for(lambda: len(masks) == 2, 60.0, group=ros_processes), ros_processes.logs()
        time.sleep(0.5)
        assert masks.stamps() == [T0, T0 + 2]
        for _, _, data in masks.items:
            mask = convert.msg_to_image(deserialize_message(data, Image), ("mono8",)) > 0
            assert _iou(mask, truth) > 0.8, _iou(mask, truth)
    finally:
        probe.close()
