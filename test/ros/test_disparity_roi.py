"""disparity_node ``roi``: matching follows the plant of the previous masks; a new plant is a full frame."""

import cv2
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from sensor_msgs.msg import Image  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.geometry.rectification import fusiello_rectify  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import wait_for  # noqa: E402
from test.support.nodes import T0, TIMEOUT, node_kwargs, publish_rect_infos, rect_info_publishers, textured_pair  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_disparity_node_matches_where_the_previous_masks_had_plant(harness, paper_rig):
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    node = harness.add(DisparityNode(**node_kwargs(harness, paper_rig, matcher="elas", disp_min=16, disp_max=48,
                                                   roi=True, roi_margin=16)))
    out = harness.collect(DisparityImage, "disparity")
    pl, pr = harness.publisher(Image, "left/image_rect"), harness.publisher(Image, "right/image_rect")
    masks = harness.publisher(Image, "left/mask")
    il, ir = rect_info_publishers(harness)
    harness.connect(pl, pr, il, ir, masks)
    rect = fusiello_rectify(paper_rig.P_left, paper_rig.P_right, paper_rig.image_size)
    left, right = (cv2.cvtColor(im, cv2.COLOR_BGR2GRAY) for im in textured_pair(paper_rig, 30))

    def pair(k):
        stamp = T0 + k * 10**8
        pl.publish(convert.image_to_msg(left, "mono8", stamp_ns=stamp, frame_id="rect"))
        pr.publish(convert.image_to_msg(right, "mono8", stamp_ns=stamp, frame_id="rect"))
        publish_rect_infos(il, ir, paper_rig, rect, stamp)
        assert wait_for(lambda: len(out) == k + 1, TIMEOUT)
        msg = out[k]
        win = msg.valid_window
        return (win.x_offset, win.y_offset, win.x_offset + win.width, win.y_offset + win.height)

    def mask(k, *boxes):
        m = np.zeros((480, 640), np.uint8)
        for x0, y0, x1, y1 in boxes:
            m[y0:y1, x0:x1] = 255
        masks.publish(convert.image_to_msg(m, "mono8", stamp_ns=T0 + k * 10**8, frame_id="rect"))
        before = node.stats()["counts"].get("masks_received", 0)
        assert wait_for(lambda: node.stats()["counts"].get("masks_received", 0) > before, TIMEOUT)

    full = pair(0)  # no mask yet: the whole frame
    assert full[2] - full[0] > 500 and full[3] - full[1] > 400
    plant = (250, 150, 400, 300)
    mask(0, plant)
    x0, y0, x1, y1 = pair(1)  # only around the plant of frame 0 (margin 16, aligned to 20 px)
    assert 200 <= x0 <= 234 and 100 <= y0 <= 134 and 416 <= x1 <= 440 and 316 <= y1 <= 340
    # a second plant enters at the left (the plant area doubles): the next pair is a full frame
    mask(1, plant, (40, 150, 190, 300))
    again = pair(2)
    assert again[0] < 100 and again[2] > 500
    stats = node.stats()["counts"]
    assert stats["disparities_published"] == 3
