"""Parameters a tool can trust (descriptions, ranges, integers for floats), the diagnostics
publisher, and the package's declared dependencies."""
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rcl_interfaces.msg import ParameterType  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from canopy_stereo.errors import CanopyStereoError  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.context import ros_context  # noqa: E402
from canopy_stereo.ros.params import rig_parameter_overrides  # noqa: E402
from test.conftest import REPO  # noqa: E402

pytestmark = pytest.mark.ros

#: parameters rclpy declares itself
ROS_OWN = {"use_sim_time", "start_type_description_service"}


def _node_classes():
    from canopy_stereo.ros.fusion_node import FusionNode
    from canopy_stereo.ros.nodes.camera import CameraNode
    from canopy_stereo.ros.nodes.disparity import DisparityNode
    from canopy_stereo.ros.nodes.point_cloud import PointCloudNode
    from canopy_stereo.ros.nodes.rectify import RectifyNode
    from canopy_stereo.ros.nodes.segment import SegmentNode

    return {"camera_node": (CameraNode, False), "rectify_node": (RectifyNode, True),
            "disparity_node": (DisparityNode, True), "segment_node": (SegmentNode, False),
            "point_cloud_node": (PointCloudNode, True), "fusion_node": (FusionNode, True)}


@pytest.fixture(scope="module")
def ctx():
    with ros_context() as context:
        yield context


def _make(ctx, cls, with_rig, **params):
    rig = load_rig(REPO / "config" / "croton_rig.yaml")
    overrides = (rig_parameter_overrides(rig) if with_rig else []) + [Parameter(k, value=v) for k, v in params.items()]
    return cls(context=ctx, parameter_overrides=overrides, start_parameter_services=False,
               namespace="/stereo")


@pytest.mark.parametrize("name", sorted(_node_classes()))
def test_every_parameter_has_a_description_and_numbers_a_range(ctx, name):
    cls, with_rig = _node_classes()[name]
    node = _make(ctx, cls, with_rig)
    try:
        names = [n for n in node._parameters if n not in ROS_OWN and not n.startswith("qos_overrides.")]
        descriptors = dict(zip(names, node.describe_parameters(names)))
        descriptions = {}
        for pname, d in descriptors.items():
            assert len(d.description) >= 10, f"{name}.{pname} has no real description: {d.description!r}"
            value = node.get_parameter(pname).value
            numeric = d.type in (ParameterType.PARAMETER_INTEGER, ParameterType.PARAMETER_DOUBLE) or (
                isinstance(value, (int, float)) and not isinstance(value, bool))
            if numeric:
                assert d.integer_range or d.floating_point_range, f"{name}.{pname} has no range"
            if d.integer_range:
                r = d.integer_range[0]
                assert r.from_value < r.to_value
                if isinstance(value, int) and not isinstance(value, bool):
                    assert r.from_value <= value <= r.to_value, f"{name}.{pname} default out of range"
            if d.floating_point_range:
                r = d.floating_point_range[0]
                assert r.from_value < r.to_value
                if isinstance(value, float):
                    assert r.from_value <= value <= r.to_value, f"{name}.{pname} default out of range"
            descriptions.setdefault(d.description, []).append(pname)
        shared = {desc: ps for desc, ps in descriptions.items() if len(ps) > 1}
        assert not shared, f"{name}: parameters share one description: {shared}"
    finally:
        node.destroy_node()


def test_camera_parameters_describe_themselves_and_take_integer_fps(ctx, tmp_path):
    from canopy_stereo.ros.nodes.camera import CameraNode

    node = _make(ctx, CameraNode, False, fps=10, device=str(tmp_path / "none_%03d.png"))
    try:
        assert node.get_parameter("fps").value == 10.0
        assert node.get_parameter("fps").type_ == Parameter.Type.DOUBLE
        d = {n: node.describe_parameter(n) for n in ("width", "fps", "frame_id", "loop")}
        assert "width" in d["width"].description and d["width"].integer_range[0].to_value >= 4096
        assert "frames per second" in d["fps"].description
        assert "frame_id" in d["frame_id"].description
        assert "restart" in d["loop"].description
    finally:
        node.destroy_node()


def test_runtime_integer_for_a_float_parameter_and_ranges_are_enforced(ctx):
    from canopy_stereo.ros.nodes.segment import SegmentNode

    node = _make(ctx, SegmentNode, False)
    try:
        ok = node.set_parameters([Parameter("scale", value=1)])[0]
        assert ok.successful and node.get_parameter("scale").value == 1.0
        bad = node.set_parameters([Parameter("scale", value=2.5)])[0]
        assert not bad.successful and "out of range" in bad.reason
        assert not node.set_parameters([Parameter("iterations", value=0)])[0].successful
    finally:
        node.destroy_node()


def test_an_out_of_range_parameter_stops_the_node_with_one_line(ctx):
    from canopy_stereo.ros.nodes.segment import SegmentNode

    with pytest.raises(CanopyStereoError, match="scale"):
        _make(ctx, SegmentNode, False, scale=5.0)


@pytest.mark.slow
def test_camera_node_process_accepts_integer_fps(tmp_path, repo_root):
    """``camera_node --ros-args -p fps:=10`` (crashed before: an integer for a double)."""
    import os

    from canopy_stereo.ros.context import private_domain_id

    env = dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    code = ("import sys, threading, os, signal; from canopy_stereo.ros.nodes.camera import main; "
            "threading.Timer(3.0, lambda: os.kill(os.getpid(), signal.SIGINT)).start(); sys.exit(main())")
    out = subprocess.run([sys.executable, "-c", code, "--ros-args", "-p", "fps:=10", "-p",
                          f"device:={tmp_path / 'none_%03d.png'}", "-p", "width:=640"],
                         env=env, capture_output=True, text=True, timeout=60, cwd=repo_root)
    assert out.returncode == 0, out.stderr
    code = "import sys; from canopy_stereo.ros.nodes.camera import main; sys.exit(main())"
    out = subprocess.run([sys.executable, "-c", code, "--ros-args", "-p", "fps:=-3"],
                         env=env, capture_output=True, text=True, timeout=60, cwd=repo_root)
    assert out.returncode == 2 and "fps" in out.stderr and out.stderr.count("\n") == 1, out.stderr


def test_diagnostics_report_rates_drops_latency_and_statistics(ctx):
    import time

    from diagnostic_msgs.msg import DiagnosticStatus

    from canopy_stereo.ros.diagnostics import status_values
    from canopy_stereo.ros.nodes.base import CanopyNode

    node = CanopyNode("diag_test", context=ctx, start_parameter_services=False,
                      parameter_overrides=[Parameter("diagnostic_period", value=0)])
    try:
        d = node.diagnostics
        assert d.pub is None  # period 0: nothing published
        for k in range(10):
            d.received("/in", k)
            d.sample("pair offset ms", 4.0 + k % 2)
        time.sleep(0.05)
        for k in range(8):
            d.published("/out", k)
        node.drop("too small", "frame")
        st = d.status()
        v = status_values(st)
        assert st.level == DiagnosticStatus.WARN and "too small" in st.message
        assert v["in /in total"] == "10" and v["out /out total"] == "8"
        window = float(v["window s"])  # the rates are the counts over the window (3 significant digits)
        assert window >= 0.05 and v["dropped"] == "1" and v["dropped: frame: too small"] == "1"
        assert float(v["in /in Hz"]) == pytest.approx(10 / window, rel=0.01)
        assert float(v["out /out Hz"]) == pytest.approx(8 / window, rel=0.01)
        assert float(v["latency median ms"]) >= 50 * 0.9
        assert float(v["pair offset ms mean"]) == pytest.approx(4.5)
        assert float(v["pair offset ms max"]) == 5.0
        st2 = d.status()  # a new window: nothing dropped, no input
        assert st2.level == DiagnosticStatus.OK and status_values(st2)["dropped"] == "0"
        assert status_values(st2)["in /in total"] == "10"
    finally:
        node.destroy_node()


def test_package_xml_declares_every_runtime_dependency():
    root = ET.parse(REPO / "package.xml").getroot()
    deps = {e.text for e in root if e.tag in ("exec_depend", "depend")}
    # the ROS packages and Python modules the package imports at run time
    for dep in ("rclpy", "sensor_msgs", "stereo_msgs", "std_msgs", "geometry_msgs", "std_srvs",
                "builtin_interfaces", "rcl_interfaces", "diagnostic_msgs", "launch", "launch_ros",
                "ament_index_python", "python3-numpy", "python3-opencv", "python3-scipy", "python3-yaml",
                "python3-numba", "mcap-ros2-support"):
        assert dep in deps, dep
    readme = (REPO / "README.md").read_text()
    assert "mcap-ros2-support" in readme and "rosdep" in readme


def test_qos_is_overridable_per_topic_with_the_standard_parameters(ctx):
    """Inputs reliable keep-last by default; ``qos_overrides.<topic>.subscription.*`` changes
    one topic (e.g. for a best-effort driver), outputs likewise."""
    from rclpy.qos import ReliabilityPolicy

    from canopy_stereo.ros.nodes.rectify import RectifyNode
    from canopy_stereo.ros.qos import INPUT_DEPTH, OUTPUT_DEPTH

    node = _make(ctx, RectifyNode, True, **{
        "qos_overrides./stereo/left/image_raw.subscription.reliability": "best_effort",
        "qos_overrides./stereo/left/image_raw.subscription.depth": 1,
        "qos_overrides./stereo/left/image_rect.publisher.reliability": "best_effort"})
    try:
        assert node.sub_left.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert node.sub_left.qos_profile.depth == 1
        assert node.sub_right.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert node.sub_right.qos_profile.depth == INPUT_DEPTH
        assert node.pub_left.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
        assert node.pub_right.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        assert node.pub_right.qos_profile.depth == OUTPUT_DEPTH
    finally:
        node.destroy_node()


def test_latest_only_processes_the_newest_jobs_and_drops_superseded_ones(ctx):
    import threading
    import time

    from canopy_stereo.ros.nodes.base import CanopyNode

    node = CanopyNode("latest_test", context=ctx, start_parameter_services=False)
    done, gate = [], threading.Event()

    def work(k):
        gate.wait(5.0)
        done.append(k)

    worker = node.latest_only(work, "pair", depth=2)
    try:
        worker.submit(0)          # taken at once, blocks on the gate
        time.sleep(0.1)
        assert node.busy
        for k in (1, 2, 3, 4):    # two may wait: 1 and 2 are superseded while 0 runs
            worker.submit(k)
        gate.set()
        deadline = time.monotonic() + 5.0
        while len(done) < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert done == [0, 3, 4]
        assert node.stats()["drops"] == {"pair: superseded by newer ones while the node was busy": 2}
    finally:
        node.destroy_node()


def test_segment_node_checks_rect_against_the_image_size(ctx):
    """A rect outside the images is refused where their size is known: at start (image_width and
    image_height given), and by a later ``ros2 param set`` once an image has been seen; one that
    fits is accepted."""
    from canopy_stereo.ros.nodes.segment import SegmentNode

    with pytest.raises(CanopyStereoError, match=r"rectangle 5000,5000,100,100 lies \(almost\) outside the 640x480"):
        _make(ctx, SegmentNode, False, image_width=640, image_height=480, rect=[5000, 5000, 100, 100])
    node = _make(ctx, SegmentNode, False, rect=[5000, 5000, 100, 100])  # size unknown yet: accepted
    try:
        node.image_size_seen = (640, 480)  # as after the first image
        result = node.set_parameters([Parameter("rect", value=[5000, 5000, 100, 100])])[0]
        assert not result.successful and "outside the 640x480 image" in result.reason
        assert node.set_parameters([Parameter("rect", value=[100, 80, 300, 250])])[0].successful
    finally:
        node.destroy_node()


def test_disparity_node_checks_disp_max_against_the_image_width(ctx):
    """The rig's image_width is known: a disp_max at or beyond it is refused at start and by a
    later ``ros2 param set``."""
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    with pytest.raises(CanopyStereoError, match=r"disp_max \(700\) must be smaller than the image width \(640 px\)"):
        _make(ctx, DisparityNode, True, disp_max=700)
    node = _make(ctx, DisparityNode, True)
    try:
        result = node.set_parameters([Parameter("disp_max", value=640)])[0]
        assert not result.successful and "image width (640 px)" in result.reason
        assert node.set_parameters([Parameter("disp_max", value=96)])[0].successful
    finally:
        node.destroy_node()
