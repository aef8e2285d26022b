"""Hostile messages into the nodes: refused from the header, logged, counted, memory given back.

The unit tests check :mod:`canopy_stereo.ros.limits` on hand-made messages; the
process test runs rectify, disparity, segment and point_cloud nodes as separate
processes (as ``ros2 run`` users do), sends an oversize and a 1x1 image (and a
NaN disparity) into every input, and checks that each node logs the drop, that
the next good pair still becomes a cloud, and that every process's RSS is back
within 20 % of its steady level within 10 s.
"""
import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from sensor_msgs.msg import Image, PointCloud2, PointField  # noqa: E402
from stereo_msgs.msg import DisparityImage  # noqa: E402

from canopy_stereo.errors import ImageError  # noqa: E402
from canopy_stereo.ros import convert, limits  # noqa: E402
from canopy_stereo.ros.context import private_domain_id, wait_for  # noqa: E402
from canopy_stereo.ros.qos import publisher_qos, recording_qos  # noqa: E402
from test.conftest import REPO  # noqa: E402

T0 = 1_700_000_000_000_000_000


# --------------------------------------------------------------------------- limits, unit level


def _image(w, h, encoding="bgr8", data_bytes=None, step=None):
    dtype, ch = convert.ENCODINGS[encoding]
    step = w * ch * np.dtype(dtype).itemsize if step is None else step
    n = step * h if data_bytes is None else data_bytes
    return Image(width=w, height=h, encoding=encoding, step=step, data=bytes(n))


@pytest.mark.parametrize("msg, kwargs, words", [
    (_image(640, 480), dict(expected_size=(640, 480)), None),
    (_image(1, 1), dict(expected_size=(640, 480)), "1x1 but 640x480 is expected"),
    (_image(1280, 960), dict(expected_size=(640, 480)), "1280x960 but 640x480"),
    (_image(40, 30), dict(min_size=(32, 32)), "smaller than 32x32"),
    (_image(0, 480, data_bytes=0), {}, "empty image"),
    (_image(640, 480, "32FC1"), dict(encodings=convert.COLOUR_ENCODINGS), "'32FC1' not accepted"),
    (_image(640, 480, "bgr8", step=100), {}, "step 100 is smaller than a row"),
    (_image(640, 480, data_bytes=10), {}, "10 bytes, 921600 expected"),
    (_image(640, 480, data_bytes=921601), {}, "921601 bytes, 921600 expected"),
])
def test_check_image_msg_reads_only_the_header(msg, kwargs, words):
    if words is None:
        limits.check_image_msg(msg, **kwargs)
        return
    with pytest.raises(ImageError, match=words.replace("(", r"\(").replace(")", r"\)")):
        limits.check_image_msg(msg, **kwargs)


def test_a_megabyte_encoding_name_is_not_repeated_in_the_log():
    msg = _image(4, 4)
    msg.encoding = "x" * 1_000_000
    with pytest.raises(ImageError) as info:
        limits.check_image_msg(msg)
    assert len(str(info.value)) < 120 and "1000000 characters" in str(info.value)


def test_hard_maxima_apply_without_a_rig():
    # 8000x8000 bgr8 claimed with an empty payload: refused on the pixel count, nothing decoded
    msg = Image(width=8000, height=8000, encoding="bgr8", step=24000, data=b"")
    with pytest.raises(ImageError, match=r"8000x8000 \(64.0 Mpx\), over the limit of 16.8 Mpx"):
        limits.check_image_msg(msg)
    msg = Image(width=4000, height=4000, encoding="rgba8", step=4000 * 4 * 3, data=b"")
    with pytest.raises(ImageError, match="MiB is over the limit of 128 MiB"):
        limits.check_image_msg(msg)


def _disparity(values, **fields):
    msg = convert.disparity_to_msg(np.full((48, 64), 20.0, np.float32), 600.0, 0.03, 0, 60)
    if values is not None:
        msg.image.data = np.ascontiguousarray(values, "<f4").tobytes()
    for k, v in fields.items():
        setattr(msg, k, v)
    return msg


@pytest.mark.parametrize("values, fields, words", [
    (None, {}, None),
    (np.full((48, 64), np.nan), {}, "3072 non-finite value"),
    (np.where(np.arange(48 * 64).reshape(48, 64) == 5, np.inf, 20.0), {}, "1 non-finite value"),
    (None, {"f": float("nan")}, "non-finite f = nan"),
    (None, {"t": float("inf"), "delta_d": float("nan")}, "non-finite t = inf, delta_d = nan"),
    (None, {"min_disparity": 70.0}, "min_disparity 70 >= max_disparity 60"),
])
def test_check_disparity_msg_refuses_non_finite_values(values, fields, words):
    msg = _disparity(values, **fields)
    if words is None:
        limits.check_disparity_msg(msg, expected_size=(64, 48))
        return
    with pytest.raises(ImageError, match=words):
        limits.check_disparity_msg(msg, expected_size=(64, 48))
    if "non-finite value" in words:  # pixels=False: the header and scalars only
        limits.check_disparity_msg(msg, expected_size=(64, 48), pixels=False)
    else:
        with pytest.raises(ImageError, match=words):
            limits.check_disparity_msg(msg, expected_size=(64, 48), pixels=False)


def test_check_cloud_msg():
    pts = np.zeros((100, 3), np.float32)
    good = convert.points_to_cloud2(pts, np.zeros((100, 3), np.uint8))
    limits.check_cloud_msg(good, max_points=100)
    with pytest.raises(ImageError, match="100 points .* over the limit of 99"):
        limits.check_cloud_msg(good, max_points=99)
    bad = convert.points_to_cloud2(pts)
    bad.fields = list(bad.fields) + [PointField(name="w", offset=bad.point_step, datatype=7, count=1)]
    with pytest.raises(ImageError, match="field 'w' .* does not fit"):
        limits.check_cloud_msg(bad)
    short = convert.points_to_cloud2(pts)
    short.data = bytes(10)
    with pytest.raises(ImageError, match="10 bytes, 1200 expected"):
        limits.check_cloud_msg(short)


@pytest.mark.slow
def test_refusing_an_oversize_message_schedules_one_release(monkeypatch):
    calls = []
    monkeypatch.setattr("canopy_stereo.ros.context.release_free_memory",
                        lambda hold_s=0.0: calls.append(hold_s) or True)
    big = _image(4000, 3000)  # 36 MB of payload
    for _ in range(3):
        with pytest.raises(ImageError):
            limits.check_image_msg(big, expected_size=(640, 480))
    assert wait_for(lambda: calls, 5.0)
    time.sleep(limits.RELEASE_DELAY_S + 0.3)
    assert calls == [limits.RELEASE_HOLD_S]  # merged into one release
    with pytest.raises(ImageError):
        limits.check_image_msg(_image(1, 1), expected_size=(640, 480))  # small: no release
    time.sleep(limits.RELEASE_DELAY_S + 0.3)
    assert calls == [limits.RELEASE_HOLD_S]


# --------------------------------------------------------------------------- nodes as processes

#: node -> (module, extra parameters)
NODES = {
    "rectify_node": ("canopy_stereo.ros.nodes.rectify", []),
    "disparity_node": ("canopy_stereo.ros.nodes.disparity", ["matcher:=sgbm"]),
    "segment_node": ("canopy_stereo.ros.nodes.segment", []),
    "point_cloud_node": ("canopy_stereo.ros.nodes.point_cloud", ["use_mask:=true"]),
}
#: topic (under /stereo) -> what is published on it
INPUTS = {
    "rectify_node": ["left/image_raw", "right/image_raw"],
    "disparity_node": ["left/image_rect", "right/image_rect"],
    "segment_node": ["left/image_rect_color"],
    "point_cloud_node": ["disparity", "left/image_rect_color", "left/mask"],
}
OVERSIZE = (4000, 3000)  # 12 Mpx: under the hard maximum, so the rig's size is what refuses it


def rss_bytes(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


def _start_node(name, rig_file, env, log_path):
    module, extra = NODES[name]
    reliable = [f"qos_overrides./stereo/{t}.subscription.reliability:=reliable" for t in INPUTS[name]]
    args = [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())",
            "--ros-args", "--params-file", str(rig_file)]
    for p in extra + reliable:
        args += ["-p", p]
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=open(log_path, "w"))


def _hostile_messages(stamp):
    """(topic, message) pairs: an oversize and a 1x1 image for every input, a NaN disparity."""
    w, h = OVERSIZE
    big_bgr = convert.image_to_msg(np.zeros((h, w, 3), np.uint8), "bgr8", stamp_ns=stamp)
    big_mono = convert.image_to_msg(np.zeros((h, w), np.uint8), "mono8", stamp_ns=stamp)
    tiny_bgr = convert.image_to_msg(np.zeros((1, 1, 3), np.uint8), "bgr8", stamp_ns=stamp + 1)
    tiny_mono = convert.image_to_msg(np.zeros((1, 1), np.uint8), "mono8", stamp_ns=stamp + 1)
    big_disp = convert.disparity_to_msg(np.zeros((h, w), np.float32), 600.0, 0.03, 0, 60, stamp_ns=stamp)
    tiny_disp = convert.disparity_to_msg(np.zeros((1, 1), np.float32), 600.0, 0.03, 0, 60, stamp_ns=stamp + 1)
    nan_disp = convert.disparity_to_msg(np.zeros((480, 640), np.float32), 600.0, 0.03, 0, 60, stamp_ns=stamp + 2)
    nan_disp.image.data = np.full((480, 640), np.nan, "<f4").tobytes()
    return [
        ("left/image_raw", big_bgr), ("right/image_raw", big_bgr),
        ("left/image_raw", tiny_bgr), ("right/image_raw", tiny_bgr),
        ("left/image_rect", big_mono), ("right/image_rect", big_mono),
        ("left/image_rect", tiny_mono), ("right/image_rect", tiny_mono),
        ("left/image_rect_color", big_bgr), ("left/image_rect_color", tiny_bgr),
        ("left/mask", big_mono), ("left/mask", tiny_mono),
        ("disparity", big_disp), ("disparity", tiny_disp), ("disparity", nan_disp),
    ]


#: words each node's log must hold after the burst
EXPECTED_LOG = {
    "rectify_node": ["4000x3000 but 640x480 is expected", "1x1 but 640x480 is expected"],
    "disparity_node": ["4000x3000 but 640x480 is expected", "1x1 but 640x480 is expected"],
    "segment_node": ["4000x3000 but 640x480 is expected", "1x1 but 640x480 is expected"],
    "point_cloud_node": ["4000x3000 but 640x480 is expected", "1x1 but 640x480 is expected",
                         "non-finite value"],
}


@pytest.mark.slow
@pytest.mark.ros
def test_hostile_burst_into_node_processes_is_dropped_logged_and_memory_returns(harness, tmp_path):
    from canopy_stereo.bag import BagReader

    rig_file = REPO / "config" / "croton_rig.yaml"
    bag = BagReader(REPO / "bags" / "croton.mcap")
    left = convert.msg_to_image(next(m for _, m in bag.read("/stereo/left/image_raw"))).copy()
    right = convert.msg_to_image(next(m for _, m in bag.read("/stereo/right/image_raw"))).copy()
    domain = private_domain_id()
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
    logs = {name: tmp_path / f"{name}.log" for name in NODES}
    procs = {name: _start_node(name, rig_file, env, logs[name]) for name in NODES}
    try:
        helper = harness.helper  # /stereo/test_helper, on the processes' private domain
        clouds = []
        helper.create_subscription(PointCloud2, "points2", clouds.append, recording_qos(depth=5))
        topics = sorted({t for ts in INPUTS.values() for t in ts})
        pubs = {t: helper.create_publisher(DisparityImage if t == "disparity" else Image, t,
                                           publisher_qos(depth=20)) for t in topics}

        def spin_until(predicate, timeout):  # the harness spins in its thread
            return wait_for(predicate, timeout)

        def send_good_pair(k):
            stamp = T0 + k * 100_000_000
            n = len(clouds)
            pubs["left/image_raw"].publish(convert.image_to_msg(left, "bgr8", stamp_ns=stamp, frame_id="left_camera"))
            pubs["right/image_raw"].publish(
                convert.image_to_msg(right, "bgr8", stamp_ns=stamp, frame_id="right_camera"))
            assert spin_until(lambda: len(clouds) > n, 90.0), f"no cloud for good pair {k}: " + _tails(logs)
            return clouds[-1]

        for name, proc in procs.items():
            assert proc.poll() is None, f"{name} exited: " + _tails(logs)
        # every node subscribed to every input topic it has, and the cloud publisher matched
        assert spin_until(lambda: all(pubs[t].get_subscription_count() >= sum(t in v for v in INPUTS.values())
                                      for t in topics) and helper.count_publishers("/stereo/points2") >= 1,
                          60.0), "nodes did not connect: " + _tails(logs)
        # the nodes discover each other on their own: resend the first pair until it comes through
        def first_cloud(k):
            stamp = T0 + k * 100_000_000
            pubs["left/image_raw"].publish(convert.image_to_msg(left, "bgr8", stamp_ns=stamp, frame_id="left_camera"))
            pubs["right/image_raw"].publish(
                convert.image_to_msg(right, "bgr8", stamp_ns=stamp, frame_id="right_camera"))
            return spin_until(lambda: len(clouds) > 0, 10.0)

        assert any(first_cloud(k) for k in range(12)), "no first cloud: " + _tails(logs)
        for k in range(12, 15):  # warm up (compilation, first allocations), then the steady level
            send_good_pair(k)
        spin_until(lambda: False, 1.0)
        steady = {name: rss_bytes(p.pid) for name, p in procs.items()}

        for topic, msg in _hostile_messages(T0 + 30 * 100_000_000):
            pubs[topic].publish(msg)
        assert spin_until(lambda: all(all(w in logs[n].read_text() for w in words)
                                      for n, words in EXPECTED_LOG.items()), 60.0), \
            "drops not logged: " + _tails(logs)
        cloud = send_good_pair(40)  # the next good pair still becomes a cloud
        assert cloud.width * cloud.height > 1000

        t_good = time.monotonic()
        back = spin_until(lambda: all(rss_bytes(p.pid) <= 1.2 * steady[n] for n, p in procs.items()), 10.0)
        after = {name: rss_bytes(p.pid) for name, p in procs.items()}
        report = ", ".join(f"{n} {steady[n] / 2**20:.0f} -> {after[n] / 2**20:.0f} MiB" for n in NODES)
        print(f"RSS steady -> after burst ({time.monotonic() - t_good:.1f} s): {report}")
        assert back, f"RSS not back within 20 % in 10 s: {report}"
        for name, proc in procs.items():
            assert proc.poll() is None, f"{name} died"
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(2)
        for proc in procs.values():
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    for name in NODES:
        text = logs[name].read_text()
        assert "Traceback" not in text and "internal error" not in text, text


def _tails(logs) -> str:
    return " | ".join(f"{n}: {p.read_text()[-600:]}" for n, p in logs.items())


# --------------------------------------------------------------------------- fusion_node


@pytest.mark.ros
def test_fusion_node_drops_hostile_clouds_and_keeps_fusing(fusion_harness):
    from test.support.fusion import latest_model, patch_cloud_m, send_cloud

    node, clouds, poses, reset, models = fusion_harness
    huge = convert.points_to_cloud2(np.zeros((4, 3), np.float32), None, stamp_ns=T0, frame_id="canopy_world")
    huge.width, huge.height, huge.row_step = 5000, 4000, 5000 * huge.point_step  # claims 20 Mpx, carries 48 B
    short = convert.points_to_cloud2(np.zeros((100, 3), np.float32), None, stamp_ns=T0 + 1,
                                     frame_id="canopy_world")
    short.data = bytes(12)
    for msg in (huge, short):
        clouds.publish(msg)
    assert wait_for(lambda: sum(node.stats()["drops"].values()) >= 2, 30.0)
    text = " | ".join(node.stats()["drops"])
    assert "20000000 points (5000x4000), over the limit" in text and "12 bytes, 1200 expected" in text
    pts, cols = patch_cloud_m()
    send_cloud(clouds, pts, cols, 5)
    model, _ = latest_model(models, 0)
    assert len(model) > 1000


def test_drop_counters_stay_bounded_under_varying_hostile_sizes(harness):
    from canopy_stereo.ros.nodes import base
    from canopy_stereo.ros.nodes.segment import SegmentNode
    from test.support.nodes import node_kwargs

    node = harness.add(SegmentNode(**node_kwargs(harness, image_width=64, image_height=48)))
    for k in range(base.MAX_DROP_REASONS + 50):
        node.drop(f"image is {k + 1}x1 but 64x48 is expected", "message")
    drops = node.stats()["drops"]
    assert len(drops) == base.MAX_DROP_REASONS + 1
    assert drops["message: other reasons"] == 50 and sum(drops.values()) == base.MAX_DROP_REASONS + 50


# --------------------------------------------------------------------------- middleware profile


@pytest.mark.parametrize("user_env, applied", [
    ({}, True),
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"}, False),
    ({"RMW_FASTRTPS_USE_QOS_FROM_XML": "0"}, False),
])
@pytest.mark.slow
def test_bounded_dds_memory_profile_unless_the_user_configures_fast_dds(tmp_path, user_env, applied):
    code = ("import os, rclpy; from canopy_stereo.ros.context import use_bounded_dds_memory as u; "
            "print(u(), os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE'), "
            "os.environ.get('RMW_FASTRTPS_USE_QOS_FROM_XML'))\n"
            "if os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') == 'rmw_fastrtps_cpp':\n"
            "    rclpy.init(); n = rclpy.create_node('profile_check'); n.destroy_node(); rclpy.shutdown()")
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("FASTRTPS_", "FASTDDS_", "RMW_FASTRTPS_", "RMW_IMPLEMENTATION"))}
    env.update(user_env, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    first = out.stdout.split()
    from canopy_stereo.ros.context import FASTDDS_PROFILES

    if applied:
        assert first == ["True", str(FASTDDS_PROFILES), "1"]
    else:
        assert first[0] == "False" and str(FASTDDS_PROFILES) not in out.stdout
    assert "XMLPARSER" not in out.stderr and "Error" not in out.stderr, out.stderr  # the profile parses


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/dev/shm"), reason="no POSIX shared memory directory")
def test_fast_dds_shared_memory_segment_holds_several_frames(tmp_path):
    """A node process's participant gets the profile's 8 MiB shared-memory segment (Fast DDS's
    512 kB default recycled a rectify_node frame's ~1.5 MB of images and camera_infos before the
    readers took them: samples lost and repaired hundreds of ms later)."""
    if os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") != "rmw_fastrtps_cpp":
        pytest.skip("another middleware")
    code = ("import os, rclpy; from canopy_stereo.ros.context import use_bounded_dds_memory as u\n"
            "assert u()\n"
            "before = set(os.listdir('/dev/shm'))\n"
            "rclpy.init(); n = rclpy.create_node('segment_check')\n"
            "print(max(os.path.getsize('/dev/shm/' + f) for f in set(os.listdir('/dev/shm')) - before\n"
            "          if f.startswith('fastrtps_') and 'port' not in f and not f.endswith('_el')))\n"
            "n.destroy_node(); rclpy.shutdown()")
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("FASTRTPS_", "FASTDDS_", "RMW_FASTRTPS_"))}
    env.update(ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                         cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout.split()[-1]) >= 8 << 20


def test_no_fast_dds_profile_for_another_middleware(monkeypatch):
    from canopy_stereo.ros import context

    for k in ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE", "RMW_FASTRTPS_USE_QOS_FROM_XML"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    assert context.use_bounded_dds_memory() is False
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in os.environ
