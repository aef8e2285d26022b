"""Views of serialized Image / DisparityImage messages read the fields rclpy deserialises."""
import numpy as np
import pytest

pytest.importorskip("rclpy")

from rclpy.serialization import serialize_message  # noqa: E402

from canopy_stereo.errors import ImageError  # noqa: E402
from canopy_stereo.ros.cdr_views import disparity_view, image_view  # noqa: E402
from canopy_stereo.ros.convert import (  # noqa: E402
    disparity_to_msg,
    image_to_msg,
    msg_to_bgr,
    msg_to_disparity,
    msg_to_image,
)
from canopy_stereo.ros.limits import check_disparity_msg, check_image_msg  # noqa: E402


def _same_image(view, msg):
    for name in ("height", "width", "encoding", "is_bigendian", "step"):
        assert getattr(view, name) == getattr(msg, name), name
    assert (view.header.stamp.sec, view.header.stamp.nanosec, view.header.frame_id) == (
        msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id)
    assert bytes(view.data) == bytes(msg.data)


@pytest.mark.parametrize("frame_id", ["", "a", "ab", "abc", "left_optical_frame", "ünï"])
def test_image_view_reads_every_field_at_any_string_alignment(frame_id):
    rng = np.random.default_rng(len(frame_id))
    for image, encoding in ((rng.integers(0, 256, (5, 7, 3), dtype=np.uint8), "bgr8"),
                            (rng.integers(0, 256, (6, 3), dtype=np.uint8), "mono8"),
                            (rng.random((4, 5)).astype(np.float32), "32FC1")):
        msg = image_to_msg(image, encoding, stamp_ns=1_700_000_000_123_456_789, frame_id=frame_id)
        view = image_view(serialize_message(msg))
        _same_image(view, msg)
        check_image_msg(view, expected_size=(image.shape[1], image.shape[0]))
        assert np.array_equal(msg_to_image(view), image)
        if encoding == "bgr8":
            assert np.array_equal(msg_to_bgr(view), image)


@pytest.mark.parametrize("frame_id", ["", "abc", "rect_left"])
def test_disparity_view_converts_like_the_message(frame_id):
    rng = np.random.default_rng(7)
    disp = (rng.random((9, 11)) * 40).astype(np.float32)
    disp[rng.random(disp.shape) < 0.3] = np.nan
    msg = disparity_to_msg(disp, 512.5, 0.0625, 2.0, 48.0, delta_d=0.25, stamp_ns=5_000_000_017,
                           frame_id=frame_id, doffs=1.5)
    view = disparity_view(serialize_message(msg))
    _same_image(view.image, msg.image)
    for name in ("f", "t", "min_disparity", "max_disparity", "delta_d"):
        assert getattr(view, name) == getattr(msg, name), name
    for name in ("x_offset", "y_offset", "height", "width", "do_rectify"):
        assert getattr(view.valid_window, name) == getattr(msg.valid_window, name), name
    check_disparity_msg(view, expected_size=(11, 9))
    a, b = msg_to_disparity(view), msg_to_disparity(msg)
    assert np.array_equal(a.disparity, b.disparity, equal_nan=True)
    assert (a.f, a.t, a.valid_window, a.stamp_ns, a.frame_id) == (b.f, b.t, b.valid_window, b.stamp_ns, b.frame_id)


def test_views_refuse_truncated_or_foreign_bytes():
    data = serialize_message(image_to_msg(np.zeros((4, 4), np.uint8), "mono8"))
    for bad in (data[:-3], data[:10], b"\x07\x01\x00\x00" + data[4:], b""):
        with pytest.raises(ImageError):
            image_view(bad)
