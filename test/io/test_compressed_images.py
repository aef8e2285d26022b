"""Compressed camera frames: every format string drivers write, corrupt data, CDR without ROS,
one-device stereo frames and capture stamps (the pure core of the compressed transport)."""
import cv2
import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.camera_frames import is_encoded, prepare_frame, split_views
from canopy_stereo.io.capture_stamps import MAX_DRIVER_LATENCY_S, CaptureClock
from canopy_stereo.io.compressed_image import (
    compressed_image_cdr,
    compressed_topic,
    encode_frame_cdr,
    parse_compressed_image_cdr,
)
from canopy_stereo.io.image_codec import decode_compressed, encode_compressed, parse_format, sniff_codec


def _scene(h=120, w=160, seed=0):
    """A smooth colour image (JPEG-friendly) with distinct B, G and R."""
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.integers(0, 255, (h, w, 3), dtype=np.uint8), (9, 9), 3)
    img[..., 0] //= 2  # blue darker than red: a channel swap would show
    return img


def _psnr(a, b) -> float:
    mse = float(np.mean((a.astype(float) - b.astype(float)) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)


@pytest.mark.parametrize("fmt", ["bgr8; jpeg compressed bgr8", "rgb8; jpeg compressed bgr8", "jpeg", "JPEG",
                                 "jpg", "image/jpeg", "", "  jpeg  ", "mjpeg"])
def test_every_jpeg_format_seen_in_the_wild_decodes_to_the_same_bgr(fmt):
    img = _scene()
    _, data = encode_compressed(img, quality=95)
    out = decode_compressed(data, fmt, expected_size=(160, 120))
    assert out.shape == (120, 160, 3) and out.dtype == np.uint8
    assert _psnr(out, img) > 35  # colour order kept: rgb8-sourced JPEGs hold ordinary JPEG colour


@pytest.mark.parametrize("fmt", ["bgr8; png compressed bgr8", "png", "image/png", ""])
def test_png_formats_are_lossless(fmt):
    img = _scene()
    out = decode_compressed(encode_compressed(img, codec="png")[1], fmt)
    assert np.array_equal(out, img)


def test_mono_jpeg_and_png_become_bgr_with_equal_channels():
    grey = _scene()[..., 1].copy()
    fmt, data = encode_compressed(grey, codec="png")
    assert fmt == "mono8; png compressed mono8"
    out = decode_compressed(data, fmt)
    assert out.shape == (120, 160, 3) and np.array_equal(out[..., 0], grey) and np.array_equal(out[..., 2], grey)
    fmt, data = encode_compressed(grey, codec="jpeg")
    assert fmt == "mono8; jpeg compressed mono8" and _psnr(decode_compressed(data, fmt)[..., 1], grey) > 35


def test_format_strings_are_parsed():
    assert parse_format("rgb8; jpeg compressed bgr8") == parse_format("rgb8;jpeg compressed bgr8")
    assert parse_format("rgb8; jpeg compressed bgr8").encoding == "rgb8"
    assert parse_format("bgr8; png compressed bgr8").codec == "png"
    assert parse_format("").codec is None and parse_format("image/png").codec == "png"


@pytest.mark.parametrize("fmt, reason", [("16UC1; compressedDepth png", "compressedDepth"),
                                         ("mono16; png compressed mono16", "not an 8-bit"),
                                         ("tiff", "unsupported compressed image format"),
                                         ("bgr8; tiff compressed bgr8", "codec must be")])
def test_formats_that_are_not_camera_frames_are_refused_with_the_reason(fmt, reason):
    _, data = encode_compressed(_scene(), codec="png")
    with pytest.raises(ImageError, match=reason):
        decode_compressed(data, fmt)


def test_corrupt_jpegs_raise_with_a_reason():
    _, data = encode_compressed(_scene(), quality=90)
    with pytest.raises(ImageError, match="corrupt JPEG: cut short"):
        decode_compressed(data[: len(data) // 2], "jpeg")
    with pytest.raises(ImageError, match="neither JPEG nor PNG"):
        decode_compressed(b"\0" * 16 + data[16:], "jpeg")
    with pytest.raises(ImageError, match="no data"):
        decode_compressed(b"", "jpeg")
    broken = data[:2] + b"\xff\xc0\x00\x02" + data[-2:]  # a frame header that says nothing
    with pytest.raises(ImageError, match="corrupt JPEG"):
        decode_compressed(broken, "jpeg")
    with pytest.raises(ImageError, match="160x120 but 640x480"):
        decode_compressed(data, "jpeg", expected_size=(640, 480))
    padded = data + b"\0" * 7  # some cameras pad their buffers: still complete
    assert decode_compressed(padded, "jpeg").shape == (120, 160, 3)


def test_sniffing():
    assert sniff_codec(encode_compressed(_scene())[1]) == "jpeg"
    assert sniff_codec(encode_compressed(_scene(), codec="png")[1]) == "png"
    assert sniff_codec(b"GIF89a") is None


def test_compressed_image_cdr_round_trips_through_rclpy():
    """The CDR written without ROS is what rclpy reads, and rclpy's is what we read."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import CompressedImage

    img = _scene()
    cdr = encode_frame_cdr(img, stamp_ns=1_700_000_000_123_456_789, frame_id="left_camera_optical_frame")
    msg = deserialize_message(cdr, CompressedImage)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert msg.header.frame_id == "left_camera_optical_frame" and msg.format == "bgr8; jpeg compressed bgr8"
    assert _psnr(decode_compressed(msg.data, msg.format), img) > 35
    for frame_id, fmt in [("", ""), ("ab", "jpeg"), ("abc", "image/png")]:
        back = parse_compressed_image_cdr(serialize_message(
            deserialize_message(compressed_image_cdr(stamp_ns=5, frame_id=frame_id, fmt=fmt, data=b"xyz"),
                                CompressedImage)))
        assert (back.stamp_ns, back.frame_id, back.format, bytes(back.data)) == (5, frame_id, fmt, b"xyz")
    with pytest.raises(ImageError, match="cut short"):
        parse_compressed_image_cdr(cdr[:40])
    assert compressed_topic("/stereo/left/image_raw") == "/stereo/left/image_raw/compressed"


def test_side_by_side_and_top_bottom_frames_split_into_left_and_right():
    left, right = _scene(seed=1), _scene(seed=2)
    a, b = split_views(np.concatenate([left, right], axis=1), "side_by_side")
    assert np.array_equal(a, left) and np.array_equal(b, right)
    a, b = split_views(np.concatenate([left, right], axis=0), "top_bottom")
    assert np.array_equal(a, left) and np.array_equal(b, right)
    with pytest.raises(ImageError, match="even width"):
        split_views(np.zeros((4, 5, 3), np.uint8), "side_by_side")
    with pytest.raises(ImageError, match="layout must be"):
        split_views(left, "anaglyph")


def test_a_devices_mjpeg_goes_out_as_it_came_and_is_decoded_only_when_needed():
    img = _scene()
    _, data = encode_compressed(img, quality=80)
    device_frame = np.frombuffer(data, np.uint8).reshape(1, -1)  # what OpenCV hands over with CONVERT_RGB off
    assert is_encoded(device_frame) and not is_encoded(img)
    [only] = prepare_frame(device_frame, transport="compressed")
    assert only.image is None and only.compressed[1] == data and only.shape == (120, 160)
    [both] = prepare_frame(device_frame, transport="both")
    assert both.compressed[1] == data and _psnr(both.image, img) > 30
    sbs = np.frombuffer(encode_compressed(np.concatenate([img, img[:, ::-1]], axis=1))[1], np.uint8)
    left, right = prepare_frame(sbs.reshape(1, -1), layout="side_by_side", transport="compressed", quality=95)
    assert left.image is None and left.shape == right.shape == (120, 160)
    assert _psnr(decode_compressed(right.compressed[1], right.compressed[0]), img[:, ::-1]) > 30
    raw_left, raw_right = prepare_frame(np.concatenate([img, img], axis=0), layout="top_bottom")
    assert raw_left.compressed is None and np.array_equal(raw_right.image, img)


def test_capture_stamps_come_from_the_driver_when_it_has_a_monotonic_capture_time():
    clock = CaptureClock(latency_s=0.05)
    ros0, mono0 = 1_700_000_000_000_000_000, 5_000_000_000
    stamps = []
    for k in range(10):
        captured = mono0 + k * 33_333_333
        latency = 20_000_000 + (k % 3) * 5_000_000  # USB transfer + decode: 20-30 ms, varying
        s = clock.stamp(receive_ns=ros0 + (captured - mono0) + latency, receive_monotonic_ns=captured + latency,
                        driver_monotonic_ns=captured)
        assert s.source == "driver"
        stamps.append(s.stamp_ns)
    # the capture instants on the ROS clock: exactly one frame period apart, no jitter
    assert np.all(np.diff(stamps) == 33_333_333) and stamps[0] == ros0
    assert clock.latency_ms == pytest.approx(25.0) and clock.jitter_ms == pytest.approx(0.0)
    # a video file's position (or no time at all) is not a capture time: reception - latency
    s = clock.stamp(receive_ns=ros0, receive_monotonic_ns=mono0, driver_monotonic_ns=1_000_000)
    assert s.source == "receive" and s.stamp_ns == ros0 - 50_000_000 and s.latency_ms is None
    s = clock.stamp(receive_ns=ros0, receive_monotonic_ns=mono0, driver_monotonic_ns=mono0 + 10**6)
    assert s.source == "receive"  # captured after it was received: not the monotonic clock
    s = clock.stamp(receive_ns=ros0, receive_monotonic_ns=mono0,
                    driver_monotonic_ns=mono0 - int((MAX_DRIVER_LATENCY_S + 1) * 1e9))
    assert s.source == "receive"
    with pytest.raises(CanopyStereoError, match="latency"):
        CaptureClock(latency_s=-1)


def test_reception_stamps_report_their_jitter():
    clock = CaptureClock()
    rng = np.random.default_rng(0)
    t = 0
    for _ in range(60):
        t += 33_000_000 + int(rng.normal(0, 2e6))
        clock.stamp(receive_ns=10**18 + t, receive_monotonic_ns=t)
    assert clock.latency_ms is None and 1.0 < clock.jitter_ms < 3.5
