"""One rig file, one rectification: a Hartley rig written by ``canopy-stereo rectify
--method hartley`` gives the same homographies however it is loaded (Python API,
``reconstruct --rig``, rectify_node with ``-p rig_file:=`` or with the file's parameters,
the in-process graph of ``canopy-stereo run``/``canopy_graph``), and a rig with bad
homographies fails with one clear line."""
import json

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import RigError
from canopy_stereo.geometry.rig_rectification import RECTIFICATION_METHODS, rectification_for_rig, validate_homography
from canopy_stereo.io.rig import load_rig, save_rig
from test.conftest import REPO

TOL = 1e-12


@pytest.fixture(scope="module")
def hartley_rig_file(tmp_path_factory):
    """``rig_hartley.yaml`` written by ``canopy-stereo rectify --method hartley`` for the
    bundled croton's first pair (the croton rig carries a Fusiello disparity range)."""
    from canopy_stereo.cli import main
    from test.support.ros_harness import croton_frames

    d = tmp_path_factory.mktemp("hartley")
    left, right = croton_frames()[0]
    cv2.imwrite(str(d / "left.png"), left)
    cv2.imwrite(str(d / "right.png"), right)
    code = main(["rectify", str(d / "left.png"), str(d / "right.png"), "--rig",
                 str(REPO / "config/croton_rig.yaml"), "--method", "hartley", "-o", str(d / "rect")])
    assert code == 0
    return d / "rect" / "rig_hartley.yaml"


@pytest.fixture(scope="module")
def hartley_reference(hartley_rig_file):
    """The homographies as written in the file (the reference of every path)."""
    rig = load_rig(hartley_rig_file)
    return (np.asarray(rig.extra["H_left"], np.float64).reshape(3, 3),
            np.asarray(rig.extra["H_right"], np.float64).reshape(3, 3))


def _same(rect, reference):
    assert rect.method == "hartley"
    assert rect.size == (640, 480)
    assert np.max(np.abs(rect.H_left - reference[0])) <= TOL
    assert np.max(np.abs(rect.H_right - reference[1])) <= TOL


def test_rectify_writes_the_hartley_rig_with_its_own_disparity_range(hartley_rig_file):
    rig = load_rig(hartley_rig_file)
    original = load_rig(REPO / "config/croton_rig.yaml")
    assert rig.extra["method"] == "hartley"
    assert len(rig.extra["H_left"]) == 9 and len(rig.extra["H_right"]) == 9
    # the Fusiello range of the croton rig (12..42) is replaced by the Hartley estimate's
    assert (rig.extra["disp_min"], rig.extra["disp_max"]) != (original.extra["disp_min"],
                                                              original.extra["disp_max"])
    assert 0 <= rig.extra["disp_min"] < rig.extra["disp_max"] <= 128
    assert rig.extra["elas"] == {"subpixel": True}  # other extras kept


def test_python_api_reads_the_rigs_method_and_homographies(hartley_rig_file, hartley_reference):
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair, rectify_rig

    rig = load_rig(hartley_rig_file)
    _same(rectification_for_rig(rig), hartley_reference)
    _same(rectify_rig(rig), hartley_reference)
    rect = rectify_rig(rig)
    assert rect.disparity_range == (rig.extra["disp_min"], rig.extra["disp_max"])
    left = cv2.imread(str(hartley_rig_file.parent.parent / "left.png"))
    right = cv2.imread(str(hartley_rig_file.parent.parent / "right.png"))
    rec = reconstruct_pair(left, right, rig, matcher="sgbm")
    _same(rec.rectification, hartley_reference)
    # an explicit method overrides the rig's
    assert rectification_for_rig(rig, method="fusiello").method == "fusiello"
    assert rectify_rig(rig, "fusiello").method == "fusiello"


def test_reconstruct_cli_uses_the_rigs_hartley_rectification(cli, monkeypatch, tmp_path, hartley_rig_file,
                                                             hartley_reference):
    import canopy_stereo.pipeline.reconstruct as pipeline

    used = []
    real = pipeline.cached_rectifier

    def spy(rig, rect, *args, **kwargs):
        used.append(rect)
        return real(rig, rect, *args, **kwargs)

    monkeypatch.setattr(pipeline, "cached_rectifier", spy)
    folder = hartley_rig_file.parent.parent
    code, out, err = cli("reconstruct", folder / "left.png", folder / "right.png", "--rig", hartley_rig_file,
                         "--matcher", "sgbm", "-o", tmp_path / "c.ply")
    assert code == 0, err
    assert used  # the pair, and the pair exchanged for the swapped-pair check: the same rectification
    for rect in used:
        _same(rect, hartley_reference)
    rig = load_rig(hartley_rig_file)
    assert f"disparity range searched {rig.extra['disp_min']}..{rig.extra['disp_max']} px" in out
    assert b"method=hartley" in (tmp_path / "c.ply").read_bytes()[:2000]
    used.clear()
    code, out, err = cli("reconstruct", folder / "left.png", folder / "right.png", "--rig", hartley_rig_file,
                         "--matcher", "sgbm", "--method", "fusiello", "-o", tmp_path / "f.ply")
    assert code == 0, err
    assert used[0].method == "fusiello"


def _geometry_from_process(ros_processes, **start):
    """Start rectify_node (``start``: params/params_files) and read its latched stereo_geometry."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    from canopy_stereo.ros.stereo_geometry import parse_stereo_geometry
    from test.support.ros_harness import Probe, wait_for

    proc = ros_processes.start("rectify_node", namespace="/stereo", **start)
    probe = Probe(ros_processes.domain_id)
    try:
        got = probe.subscribe(String, "/stereo/stereo_geometry", QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        assert wait_for(lambda: len(got) > 0, 60.0, group=ros_processes), proc.log()
        with got.lock:
            data = got.items[0][2]
    finally:
        probe.close()
        proc.stop()
    msg = deserialize_message(data, String)
    assert json.loads(msg.data)["method"] == "hartley"
    return parse_stereo_geometry(msg).rectification()


@pytest.mark.ros
@pytest.mark.slow
def test_rectify_node_process_with_rig_file_parameter(ros_processes, hartley_rig_file, hartley_reference):
    pytest.importorskip("stereo_msgs.msg")
    _same(_geometry_from_process(ros_processes, params={"rig_file": str(hartley_rig_file)}), hartley_reference)


@pytest.mark.ros
@pytest.mark.slow
def test_rectify_node_process_with_the_files_parameters(ros_processes, hartley_rig_file, hartley_reference):
    pytest.importorskip("stereo_msgs.msg")
    _same(_geometry_from_process(ros_processes, params_files=[hartley_rig_file]), hartley_reference)


@pytest.mark.ros
def test_in_process_graph_and_run_check_use_the_rigs_rectification(hartley_rig_file, hartley_reference):
    pytest.importorskip("rclpy")
    pytest.importorskip("stereo_msgs.msg")
    from rclpy.parameter import Parameter

    from canopy_stereo.ros.context import ros_context
    from canopy_stereo.ros.graph import CanopyGraph, GraphOptions
    from canopy_stereo.ros.nodes.rectify import RectifyNode

    rig = load_rig(hartley_rig_file)
    with ros_context() as ctx:
        graph = CanopyGraph(rig, ctx, GraphOptions(segment=False, parameter_services=False))
        try:
            _same(graph.nodes["rectify_node"].rect, hartley_reference)
            # the rig's disparity range reaches disparity_node as its parameters
            d = graph.nodes["disparity_node"]
            assert (d.config["disp_min"], d.config["disp_max"]) == (rig.extra["disp_min"], rig.extra["disp_max"])
        finally:
            graph.shutdown()
        # rig_file with an explicit method parameter: the parameter wins
        node = RectifyNode(context=ctx, start_parameter_services=False, parameter_overrides=[
            Parameter("rig_file", value=str(hartley_rig_file)), Parameter("method", value="fusiello")])
        try:
            assert node.rect.method == "fusiello"
        finally:
            node.destroy_node()


def _rig_with(tmp_path, **extra):
    rig = load_rig(REPO / "config/paper_rig.yaml")
    path = tmp_path / "rig.yaml"
    save_rig(rig.with_extra(method="hartley", **extra), path)
    return path


GOOD = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("H_left, message", [
    ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0], "H_left must be 9 numbers"),
    ([1.0, 0.0, float("nan"), 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "H_left has non-finite entries"),
    ([1.0, 2.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0], "H_left is singular"),
    ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, -0.004, 0.0, 1.0], "H_left sends part of the 640x480 image to infinity"),
    ([0.25, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 1.0], "H_left maps the 640x480 image onto only 6%"),
])
def test_bad_homographies_fail_with_one_line(cli, tmp_path, H_left, message):
    path = _rig_with(tmp_path, H_left=H_left, H_right=GOOD)
    with pytest.raises(RigError, match=message):
        rectification_for_rig(load_rig(path))
    img = tmp_path / "img.png"
    cv2.imwrite(str(img), np.zeros((480, 640, 3), np.uint8))
    code, out, err = cli("reconstruct", img, img, "--rig", path, "--matcher", "sgbm", "-o", tmp_path / "c.ply")
    assert code == 2
    assert err.count("\n") == 1 and message in err and "Traceback" not in err, err


def test_hartley_without_homographies_and_unknown_method(tmp_path):
    rig = load_rig(REPO / "config/paper_rig.yaml")
    with pytest.raises(RigError, match="method hartley needs H_left and H_right"):
        rectification_for_rig(rig, method="hartley")
    with pytest.raises(RigError, match="unknown rectification method 'affine'.*the rig's method"):
        rectification_for_rig(rig.with_extra(method="affine"))
    assert RECTIFICATION_METHODS == ("fusiello", "hartley")
    # a Fusiello rig ignores stored homographies (they are derived from P)
    assert rectification_for_rig(rig.with_extra(method="fusiello", H_left=[0.0] * 9)).method == "fusiello"
    assert validate_homography(np.diag([2.0, 2.0, 2.0]), "H", (640, 480))[2, 2] == 1.0


@pytest.mark.ros
@pytest.mark.slow
def test_rectify_node_process_with_bad_homographies_exits_with_one_line(ros_processes, tmp_path):
    path = _rig_with(tmp_path, H_left=GOOD, H_right=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    proc = ros_processes.start("rectify_node", params={"rig_file": str(path)})
    assert proc.proc.wait(60) == 2
    log = proc.log().strip().splitlines()
    assert log == [f"error: rig file {path}: H_right is singular (not invertible)"], log
