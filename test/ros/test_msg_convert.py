"""Message <-> numpy converters round-trip (canopy_stereo.ros.convert)."""
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("sensor_msgs.msg")

from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.errors import ImageError  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402

pytestmark = pytest.mark.ros


def _wire(msg, cls):
    """Through CDR and back, as a message travels between nodes or through a bag."""
    return deserialize_message(serialize_message(msg), cls)


@pytest.mark.parametrize("encoding,dtype,shape", [
    ("bgr8", np.uint8, (7, 5, 3)), ("mono8", np.uint8, (7, 5)), ("rgba8", np.uint8, (4, 6, 4)),
    ("mono16", np.uint16, (3, 9)), ("32FC1", np.float32, (6, 4)), ("64FC1", np.float64, (2, 3)),
    ("16SC1", np.int16, (5, 5)),
])
def test_image_round_trip(encoding, dtype, shape):
    rng = np.random.default_rng(1)
    img = (rng.random(shape) * 1000).astype(dtype)
    msg = convert.image_to_msg(img, encoding, stamp_ns=12_345_678_901, frame_id="cam")
    back = convert.msg_to_image(_wire(msg, Image))
    assert back.dtype == dtype and back.shape == shape
    np.testing.assert_array_equal(back, img)
    assert msg.step == shape[1] * (shape[2] if len(shape) == 3 else 1) * np.dtype(dtype).itemsize
    assert convert.stamp_to_ns(msg.header.stamp) == 12_345_678_901
    assert msg.header.frame_id == "cam"


def test_image_with_row_padding_and_big_endian():
    img = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    rows = img.astype(">u2").tobytes()
    padded = b"".join(rows[i * 8:(i + 1) * 8] + b"\xff\xff" for i in range(3))
    msg = Image(height=3, width=4, encoding="mono16", is_bigendian=1, step=10, data=padded)
    np.testing.assert_array_equal(convert.msg_to_image(msg), img)


def test_image_errors_name_the_problem():
    msg = convert.image_to_msg(np.zeros((4, 4, 3), np.uint8), "bgr8")
    with pytest.raises(ImageError, match="not accepted"):
        convert.msg_to_image(msg, encodings=("mono8",))
    with pytest.raises(ImageError, match="expected"):
        convert.msg_to_image(msg, expected_size=(5, 4))
    bad = Image(height=4, width=4, encoding="bgr8", step=12, data=bytes(20))
    with pytest.raises(ImageError, match="bytes"):
        convert.msg_to_image(bad)
    with pytest.raises(ImageError, match="unsupported"):
        convert.msg_to_image(Image(height=1, width=1, encoding="yuv422", step=2, data=bytes(2)))
    with pytest.raises(ImageError, match="channel"):
        convert.image_to_msg(np.zeros((2, 2), np.uint8), "bgr8")


def test_bgr_and_mono_conversions():
    bgr = np.zeros((2, 3, 3), np.uint8)
    bgr[..., 0], bgr[..., 1], bgr[..., 2] = 10, 20, 30
    rgb_msg = convert.image_to_msg(bgr[..., ::-1].copy(), "rgb8")
    np.testing.assert_array_equal(convert.msg_to_bgr(rgb_msg), bgr)
    mono = convert.msg_to_mono(convert.image_to_msg(bgr, "bgr8"))
    assert mono.shape == (2, 3) and abs(int(mono[0, 0]) - round(0.114 * 10 + 0.587 * 20 + 0.299 * 30)) <= 1
    grey_msg = convert.image_to_msg(np.full((2, 2), 77, np.uint8), "mono8")
    assert np.all(convert.msg_to_bgr(grey_msg) == 77)


def test_disparity_round_trip_marks_invalid_below_min():
    d = np.array([[5.5, -1.0, 30.0], [np.nan, 12.25, 100.0]], np.float32)
    msg = convert.disparity_to_msg(d, f=640.5, t=0.0296, min_disparity=4, max_disparity=64,
                                   delta_d=0.0625, stamp_ns=7, frame_id="rect")
    msg = _wire(msg, DisparityImage)
    raw = convert.msg_to_image(msg.image)
    assert msg.image.encoding == "32FC1"
    invalid = np.array([[False, True, False], [True, False, True]])
    assert np.all(raw[invalid] < msg.min_disparity) and np.all(raw[~invalid] >= msg.min_disparity)
    frame = convert.msg_to_disparity(msg)
    np.testing.assert_array_equal(frame.disparity[~invalid], d[~invalid])
    assert np.all(np.isnan(frame.disparity[invalid]))
    assert frame.f == pytest.approx(640.5) and frame.t == pytest.approx(0.0296)
    assert (frame.min_disparity, frame.max_disparity, frame.delta_d) == (4, 64, 0.0625)
    assert frame.valid_window == (0, 0, 3, 2)
    assert frame.stamp_ns == 7 and frame.frame_id == "rect"


def test_disparity_invalid_values_and_window():
    """Every kind of invalid value (NaN, +-inf, negative, below and above the range) becomes
    min_disparity - 1; the valid window is the box of the rest; float64 maps are accepted."""
    d = np.full((5, 6), np.nan)
    d[1, 2], d[3, 4] = 10.0, 20.0  # valid
    d[0, 0], d[4, 5], d[2, 0], d[0, 5], d[4, 0] = np.inf, -np.inf, -3.0, 3.0, 70.0  # invalid
    msg = convert.disparity_to_msg(d, 500.0, 0.05, 4, 64, doffs=1.5)
    raw = convert.msg_to_image(msg.image)
    assert raw.dtype == np.float32
    assert raw[1, 2] == 8.5 and raw[3, 4] == 18.5  # shifted by doffs
    invalid = np.ones_like(raw, bool)
    invalid[1, 2] = invalid[3, 4] = False
    assert np.all(raw[invalid] == np.float32(4 - 1.5 - 1))
    w = msg.valid_window
    assert (w.x_offset, w.y_offset, w.width, w.height) == (2, 1, 3, 3)
    empty = convert.disparity_to_msg(np.full((3, 3), np.nan, np.float32), 500.0, 0.05, 0, 64).valid_window
    assert (empty.x_offset, empty.y_offset, empty.width, empty.height) == (0, 0, 0, 0)


def test_disparity_principal_point_offset_gives_ros_depth():
    """With converging rectified cameras (cx_l != cx_r) the message holds d - doffs, so Z = f t / d."""
    f, B, doffs = 640.0, 0.03, 15.5
    Z = np.array([[0.5, 0.8], [1.0, 2.0]], np.float32)
    rectified = f * B / Z + doffs  # u_left - u_right in the rectified images
    msg = convert.disparity_to_msg(rectified, f, B, 20, 60, doffs=doffs)
    assert msg.min_disparity == pytest.approx(20 - doffs) and msg.max_disparity == pytest.approx(60 - doffs)
    frame = convert.msg_to_disparity(_wire(msg, DisparityImage))
    np.testing.assert_allclose(frame.depth(), Z, rtol=1e-5)


def test_valid_window_is_bounding_box():
    d = np.full((10, 12), -1, np.float32)
    d[2:5, 3:9] = 7
    assert convert.valid_window(d) == (3, 2, 6, 3)
    assert convert.valid_window(np.full((3, 3), -1, np.float32)) == (0, 0, 0, 0)


def test_cloud_round_trip_organized_and_dense():
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(4, 5, 3)).astype(np.float32)
    pts[1, 2] = np.nan
    cols = rng.integers(0, 256, size=(4, 5, 3)).astype(np.uint8)
    msg = _wire(convert.points_to_cloud2(pts, cols, stamp_ns=99, frame_id="canopy_world"), PointCloud2)
    assert (msg.height, msg.width, msg.point_step, msg.is_dense) == (4, 5, 16, False)
    assert [f.name for f in msg.fields] == ["x", "y", "z", "rgb"]
    assert all(f.datatype == PointField.FLOAT32 for f in msg.fields)
    back, bcol = convert.cloud2_to_points(msg, organized=True)
    np.testing.assert_array_equal(back, pts)
    np.testing.assert_array_equal(bcol, cols)
    dense = convert.points_to_cloud2(pts, cols, organized=False)
    assert dense.height == 1 and dense.width == 19 and dense.is_dense
    dp, dc = convert.cloud2_to_points(dense)
    keep = np.isfinite(pts).all(axis=2)
    np.testing.assert_array_equal(dp, pts[keep])
    np.testing.assert_array_equal(dc, cols[keep])


def test_packed_rgb_matches_pcl_layout():
    packed = convert.pack_rgb(np.array([[255, 128, 1]], np.uint8))
    assert packed.view(np.uint32)[0] == 0x00FF8001
    np.testing.assert_array_equal(convert.unpack_rgb(packed), [[255, 128, 1]])


def test_packed_bgr_image_and_prepacked_cloud():
    rng = np.random.default_rng(5)
    bgr = rng.integers(0, 256, size=(6, 7, 3)).astype(np.uint8)
    packed = convert.pack_bgr_image(bgr)
    assert packed.shape == (6, 7) and packed.dtype == np.float32
    np.testing.assert_array_equal(packed.view(np.uint32), convert.pack_rgb(bgr[..., ::-1]).view(np.uint32))
    pts = rng.normal(size=(6, 7, 3)).astype(np.float32)
    pts[0, :3, 1] = np.nan  # one coordinate missing is enough to drop a point
    msg = convert.points_to_cloud2(pts, rgb=packed, organized=False)
    back, cols = convert.cloud2_to_points(msg)
    keep = np.isfinite(pts).all(axis=2)
    np.testing.assert_array_equal(back, pts[keep])
    np.testing.assert_array_equal(cols, bgr[..., ::-1][keep])
    with pytest.raises(ImageError, match="not both"):
        convert.points_to_cloud2(pts, bgr, rgb=packed)
    with pytest.raises(ImageError, match="packed rgb"):
        convert.points_to_cloud2(pts, rgb=packed[:3])


def test_cloud_reader_handles_foreign_layouts():
    """A cloud with float64 fields in another order and row padding."""
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    rec = np.zeros(2, dtype=[("pad", "<f4"), ("z", "<f8"), ("y", "<f8"), ("x", "<f8")])
    rec["x"], rec["y"], rec["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    msg = PointCloud2(height=1, width=2, point_step=28, row_step=60, is_bigendian=False,
                      data=rec.tobytes() + bytes(4),
                      fields=[PointField(name="z", offset=4, datatype=PointField.FLOAT64, count=1),
                              PointField(name="y", offset=12, datatype=PointField.FLOAT64, count=1),
                              PointField(name="x", offset=20, datatype=PointField.FLOAT64, count=1)])
    got, cols = convert.cloud2_to_points(msg)
    np.testing.assert_allclose(got, pts)
    assert cols is None


def test_rectified_camera_info_ros_conventions():
    K = np.array([[640.0, 0, 320.5], [0, 640.0, 240.25], [0, 0, 1]])
    left = _wire(convert.rectified_camera_info(K, (640, 480), 0.0296, "left", stamp_ns=5, frame_id="l"),
                 CameraInfo)
    right = _wire(convert.rectified_camera_info(K, (640, 480), 0.0296, "right", stamp_ns=5, frame_id="r"),
                  CameraInfo)
    assert (left.width, left.height) == (640, 480)
    np.testing.assert_allclose(np.reshape(left.k, (3, 3)), K)
    np.testing.assert_allclose(np.reshape(left.r, (3, 3)), np.eye(3))
    PL, PR = np.reshape(left.p, (3, 4)), np.reshape(right.p, (3, 4))
    np.testing.assert_allclose(PL[:, :3], K)
    assert PL[0, 3] == 0 and PR[0, 3] == pytest.approx(-640.0 * 0.0296)
    # image_geometry's baseline: -Tx / fx
    assert -PR[0, 3] / PR[0, 0] == pytest.approx(0.0296)
    assert list(right.d) == [0.0] * 5 and right.distortion_model == "plumb_bob"


def test_stamp_conversion():
    t = convert.ns_to_stamp(1_700_000_000_123_456_789)
    assert (t.sec, t.nanosec) == (1_700_000_000, 123_456_789)
    assert convert.stamp_to_ns(t) == 1_700_000_000_123_456_789


def test_message_buffers_one_copy_in_views_out():
    """image_to_msg / points_to_cloud2 fill the uint8[] field with one copy (an array.array);
    msg_to_image returns a view into the message's buffer, not a copy."""
    import array

    from canopy_stereo.ros.convert import message_bytes

    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    msg = convert.image_to_msg(img, "bgr8", stamp_ns=5, frame_id="cam")
    assert isinstance(msg.data, array.array) and msg.data.typecode == "B"
    view = convert.msg_to_image(msg)
    np.testing.assert_array_equal(view, img)
    assert np.shares_memory(view, np.frombuffer(msg.data, np.uint8))
    strided = np.asfortranarray(rng.random((7, 5)).astype(np.float32))
    assert message_bytes(strided).tobytes() == np.ascontiguousarray(strided).tobytes()
    pts = rng.random((10, 3)).astype(np.float32)
    cloud = convert.points_to_cloud2(pts, None, stamp_ns=1, frame_id="w", organized=False,
                                     rgb=rng.random(10).astype(np.float32))
    assert isinstance(cloud.data, array.array)
    np.testing.assert_array_equal(convert.cloud2_to_points(cloud)[0], pts)
