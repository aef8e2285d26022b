"""camera_node as a driver with camera_info_manager's conventions: ``camera_info_url``
(``file://``, ``package://``, ``${NAME}``, ``${ROS_HOME}``) and ``set_camera_info``
(what ROS's cameracalibrator calls to commit), and the URL rules themselves."""
from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import CalibrationError
from canopy_stereo.io.calibration_import.ros import camera_info_yaml, load_camera_info_yaml
from canopy_stereo.io.camera_info_url import resolve_camera_info_url

pytest.importorskip("rclpy")

from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import CameraInfo  # noqa: E402
from sensor_msgs.srv import SetCameraInfo  # noqa: E402

from canopy_stereo.geometry.frames import raw_camera_calibration  # noqa: E402
from canopy_stereo.ros import convert  # noqa: E402

pytestmark = pytest.mark.ros


def test_url_rules(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "rh"))
    assert resolve_camera_info_url("", camera_name="left") == (tmp_path / "rh" / "camera_info" / "left.yaml", True)
    assert resolve_camera_info_url("file://${ROS_HOME}/cal/${NAME}.yaml", camera_name="right") == \
        (tmp_path / "rh" / "cal" / "right.yaml", True)
    path, writable = resolve_camera_info_url("package://canopy_stereo/config/${NAME}.yaml", camera_name="x")
    assert path.parts[-2:] == ("config", "x.yaml") and path.parent.is_dir() and not writable
    for bad in ("http://host/cal.yaml", "file://relative.yaml", "package://nosuchpkg_xyz/a.yaml"):
        with pytest.raises(CalibrationError, match="camera_info_url"):
            resolve_camera_info_url(bad, camera_name="left")


def _frames(tmp_path, n=3):
    pattern = str(tmp_path / "right_%03d.png")
    for k in range(n):
        cv2.imwrite(pattern % k, np.full((480, 640, 3), 40 * (k + 1), np.uint8))
    return pattern


def _camera(harness, tmp_path, **params):
    from canopy_stereo.ros.nodes.camera import CameraNode

    overrides = [Parameter(k, value=v) for k, v in dict(device=_frames(tmp_path), fps=30.0, loop=True,
                                                        **params).items()]
    return harness.add(CameraNode(context=harness.ctx, namespace="/stereo", parameter_overrides=overrides,
                                  start_parameter_services=False, node_name="right_camera"))


def _wait(cond, timeout=20.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.05)
    return False


def test_camera_info_url_then_set_camera_info_commits(harness, paper_rig, tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "rh"))
    cal = raw_camera_calibration(paper_rig, "right")
    url_file = tmp_path / "rh" / "cams" / "right.yaml"
    url_file.parent.mkdir(parents=True)
    url_file.write_text(camera_info_yaml(cal, "right"))
    node = _camera(harness, tmp_path, camera_name="right", camera_info_url="file://${ROS_HOME}/cams/${NAME}.yaml")
    infos = harness.collect(CameraInfo, "right/camera_info")
    assert _wait(lambda: len(infos) >= 2)
    K, D, R, P = convert.camera_info_matrices(infos[-1])
    np.testing.assert_allclose(P, cal.P)
    np.testing.assert_allclose(D, cal.D)

    # cameracalibrator's commit: a new calibration through the service, published and stored
    new = convert.camera_info_msg(cal)
    new.k[0] = new.k[4] = 700.0
    new.distortion_model = "plumb_bob"
    new.d = [-0.2, 0.05, 0.001, -0.001, 0.0]
    client = harness.helper.create_client(SetCameraInfo, "/stereo/right_camera/set_camera_info")
    assert client.wait_for_service(timeout_sec=20)
    future = client.call_async(SetCameraInfo.Request(camera_info=new))
    assert _wait(future.done)
    assert future.result().success, future.result().status_message
    n = len(infos)
    assert _wait(lambda: len(infos) > n + 1)
    assert infos[-1].k[0] == 700.0 and list(infos[-1].d) == pytest.approx([-0.2, 0.05, 0.001, -0.001, 0.0])
    stored, name = load_camera_info_yaml(url_file)
    assert name == "right" and stored.K[0, 0] == 700.0 and stored.D[0] == pytest.approx(-0.2)

    # a calibration that is not one (R not a rotation) is refused with the reason, nothing stored
    bad = convert.camera_info_msg(cal)
    bad.r = [2.0, 0, 0, 0, 1, 0, 0, 0, 1]
    future = client.call_async(SetCameraInfo.Request(camera_info=bad))
    assert _wait(future.done)
    assert not future.result().success and "not a rotation" in future.result().status_message
    assert load_camera_info_yaml(url_file)[0].K[0, 0] == 700.0
    assert node.info.calibration.K[0, 0] == 700.0
