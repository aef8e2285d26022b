"""camera_node never hangs: capture off the executor, timeouts, back-off, Ctrl-C within 2 s."""
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")

from sensor_msgs.msg import Image  # noqa: E402

from canopy_stereo.ros import convert  # noqa: E402
from canopy_stereo.ros.context import private_domain_id, wait_for  # noqa: E402
from test.support.nodes import TIMEOUT, node_kwargs  # noqa: E402
from test.support.ros_harness import killed_at_exit  # noqa: E402

pytestmark = pytest.mark.ros


def _camera_process(device, log_path, *params):
    env = dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    args = [sys.executable, "-c", "import sys; from canopy_stereo.ros.nodes.camera import main; sys.exit(main())",
            "--ros-args", "-p", f"device:={device}"]
    for p in params:
        args += ["-p", p]
    return subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=open(log_path, "w"))


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_camera_node_on_a_fifo_logs_the_stall_and_stops_within_2s_of_sigint(tmp_path):
    """OpenCV blocks opening a FIFO that nobody writes to (16.5 s, deaf to Ctrl-C, when it ran
    on the executor): the node must log it as a missing source and stop at once on SIGINT."""
    fifo = tmp_path / "camera.fifo"
    os.mkfifo(fifo)
    log = tmp_path / "camera.log"
    proc = _camera_process(fifo, log, "open_timeout:=1.0")
    with killed_at_exit(proc):
        assert wait_for(lambda: "did not finish within 1 s; retrying with back-off" in log.read_text(), 60.0), \
            log.read_text()
        assert proc.poll() is None
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        stopped_s = time.monotonic() - t0
    text = log.read_text()
    assert stopped_s < 2.0, f"stopped {stopped_s:.2f} s after SIGINT"
    assert proc.returncode == 0, text
    assert "Traceback" not in text
    assert text.count("retrying with back-off") == 1  # logged once, not per attempt


@pytest.mark.slow
def test_camera_node_sigterm_on_a_healthy_sequence_stops_within_2s(tmp_path):
    import cv2

    for k in range(3):
        cv2.imwrite(str(tmp_path / f"f_{k:03d}.png"), np.full((48, 64, 3), 50 * k, np.uint8))
    log = tmp_path / "camera.log"
    proc = _camera_process(tmp_path / "f_%03d.png", log, "fps:=30.0")
    with killed_at_exit(proc):
        assert wait_for(lambda: "opened" in log.read_text(), 60.0), log.read_text()
        time.sleep(0.5)
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=10)
        stopped_s = time.monotonic() - t0
    assert stopped_s < 2.0 and proc.returncode == 0, log.read_text()


class _FakeCapture:
    """A capture that gives ``frames`` frames, then blocks in ``read`` until ``release_read`` is set."""

    def __init__(self, frames, release_read):
        self.frames, self.release_read = list(frames), release_read
        self.released = threading.Event()

    def read(self):
        if self.frames:
            time.sleep(0.02)
            return True, self.frames.pop(0)
        self.release_read.wait()
        return False, None

    def release(self):
        self.released.set()


def test_a_stalled_read_gets_the_log_and_back_off_of_a_missing_source(harness, monkeypatch):
    from canopy_stereo.ros.nodes import camera

    unblock = threading.Event()
    stalled = _FakeCapture([np.full((8, 8, 3), v, np.uint8) for v in (10, 20, 30)], unblock)
    healthy = _FakeCapture([np.full((8, 8, 3), 200, np.uint8)] * 1000, threading.Event())
    opens = []

    def fake_open(source, **settings):
        opens.append(source)
        return stalled if len(opens) == 1 else healthy

    monkeypatch.setattr(camera, "open_capture", fake_open)
    logs = []
    node = harness.add(camera.CameraNode(**node_kwargs(harness, device="/dev/video99", camera_name="left",
                                                       fps=50.0, read_timeout=0.5)))
    monkeypatch.setattr(node, "get_logger", lambda: _Recorder(logs))
    out = harness.collect(Image, "left/image_raw")
    assert wait_for(lambda: node.counts["open_failures"] >= 1, TIMEOUT)  # the read blocked 0.5 s
    assert any("/dev/video99 stalled: no frame for 0.5 s; retrying with back-off" in m for m in logs), logs
    assert node.counts["stalls"] == 1
    assert wait_for(lambda: any(int(convert.msg_to_image(m)[0, 0, 0]) == 200 for m in out), TIMEOUT)
    assert wait_for(lambda: any("camera left: /dev/video99 is back" in m for m in logs), TIMEOUT), logs
    assert [int(convert.msg_to_image(m)[0, 0, 0]) for m in out[:3]] == [10, 20, 30]
    # the abandoned capture is released by its own thread once its read returns
    assert not stalled.released.is_set()
    unblock.set()
    assert stalled.released.wait(5.0)
    assert wait_for(lambda: not node.abandoned or not any(s.is_alive() for s in node.abandoned), 5.0)


class _Recorder:
    def __init__(self, sink):
        self.sink = sink

    def info(self, msg):
        self.sink.append(msg)

    warning = warn = error = debug = info
