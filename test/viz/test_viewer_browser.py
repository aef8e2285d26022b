"""A real browser on the web viewer: headless Chromium (Debian's package) opens the page that
``canopy-stereo view BAG --web`` serves from the rerun-sdk wheel, with no network beyond
localhost, and a screenshot shows the cloud.

Chromium is driven over the DevTools protocol on a pipe (``--remote-debugging-pipe``: file
descriptors 3 and 4, NUL-separated JSON), so no extra Python package is needed. .ci/run
installs Chromium with apt-get when it is missing.
"""
from __future__ import annotations

import base64
import json
import os
import re
import select
import shutil
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from test.conftest import REPO

CROTON_BAG = REPO / "bags" / "croton.mcap"
CROTON_RIG = REPO / "config" / "croton_rig.yaml"

#: Chromium without anything that reaches beyond this machine: no background networking,
#: updates, sync or QUIC, every host name but localhost unresolvable, a fresh profile.
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE localhost, EXCLUDE 127.0.0.1",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=1280,720"]


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it with apt-get as root)")
    return exe


class DevTools:
    """A minimal DevTools-protocol client of one headless Chromium over a pipe."""

    def __init__(self, exe: str, profile, log_path):
        to_child_r, self._to_child_w = os.pipe()
        self._from_child_r, from_child_w = os.pipe()

        def child_fds():
            a, b = os.dup(to_child_r), os.dup(from_child_w)  # inheritable copies
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.log = open(log_path, "wb")
        self.proc = subprocess.Popen([exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}",
                                      "--remote-debugging-pipe", "about:blank"],
                                     stdin=subprocess.DEVNULL, stdout=self.log, stderr=self.log,
                                     close_fds=False, preexec_fn=child_fds)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buf = b""
        self._id = 0
        self.session = None

    def call(self, method: str, params=None, timeout_s: float = 60.0):
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if self.session and not method.startswith("Target."):
            msg["sessionId"] = self.session
        os.write(self._to_child_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" not in self._buf:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([self._from_child_r], [], [], left)[0]:
                    raise TimeoutError(f"chromium did not answer {method}")
                chunk = os.read(self._from_child_r, 1 << 20)
                if not chunk:
                    raise RuntimeError("chromium closed the DevTools pipe")
                self._buf += chunk
            line, self._buf = self._buf.split(b"\0", 1)
            reply = json.loads(line)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def open(self, url: str) -> None:
        target = self.call("Target.createTarget", {"url": url})["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]

    def screenshot(self) -> np.ndarray:
        import cv2

        data = base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"})["data"])
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout_s=10)
        except (RuntimeError, TimeoutError, OSError):
            pass
        try:
            self.proc.wait(15)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(5)
        for fd in (self._to_child_w, self._from_child_r):
            os.close(fd)
        self.log.close()


def leaf_green_fraction(bgr: np.ndarray) -> float:
    """Fraction of pixels that are the croton's leaf green (G above R, well above B)."""
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return float(((g > r + 10) & (g > b + 25) & (g > 60)).mean())


def mask_tint_fraction(bgr: np.ndarray) -> float:
    """Fraction of pixels tinted by the viewer's magenta plant mask (R and B well above G)."""
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return float(((r > g + 40) & (b > g + 40)).mean())


def _read_line(proc, pattern: str, timeout_s: float, seen: list) -> re.Match:
    """Wait for a line of ``proc``'s output matching ``pattern`` (a reader thread fills ``seen``)."""
    if not getattr(proc, "_line_reader", None):
        proc._line_reader = threading.Thread(target=lambda: seen.extend(iter(proc.stdout.readline, "")),
                                             daemon=True)
        proc._line_reader.start()
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for line in list(seen):
            m = re.search(pattern, line)
            if m:
                return m
        if proc.poll() is not None and not proc._line_reader.is_alive():
            break
        time.sleep(0.2)
    raise AssertionError(f"no line matching {pattern!r}; output so far: {''.join(seen)[-2000:]}")


@pytest.mark.slow
@pytest.mark.ros
def test_web_viewer_in_headless_chromium_shows_the_cloud(tmp_path):
    pytest.importorskip("rerun")
    pytest.importorskip("rclpy")
    psutil = pytest.importorskip("psutil")  # a dependency of rerun-sdk
    exe = _chromium()
    from canopy_stereo.viz.rerun_log import free_port

    port = free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    view = subprocess.Popen([sys.executable, "-m", "canopy_stereo.cli", "view", str(CROTON_BAG),
                             "--rig", str(CROTON_RIG), "--no-measure", "--web", "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=open(tmp_path / "view.err", "w"), text=True,
                            cwd=REPO, env=env)
    browser = None
    servers = []
    seen: list[str] = []
    try:
        url = _read_line(view, r"viewer: (http://127\.0\.0\.1:\d+/\S+)", 120, seen).group(1)
        assert url.startswith(f"http://127.0.0.1:{port}/")
        # the viewer server listens on localhost only
        children = servers = psutil.Process(view.pid).children(recursive=True)
        listening = [c.laddr for ch in children for c in ch.net_connections(kind="inet")
                     if c.status == psutil.CONN_LISTEN]
        assert listening and all(addr.ip == "127.0.0.1" for addr in listening), listening
        _read_line(view, r"frames through the graph, [1-9]\d* shown", 600, seen)

        browser = DevTools(exe, tmp_path / "profile", tmp_path / "chromium.log")
        browser.open(url)
        shot, green, tint = None, 0.0, 0.0
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # until both views are drawn (software WebGL is slow)
            time.sleep(3)
            shot = browser.screenshot()
            h, w = shot.shape[:2]
            cloud_view = shot[int(0.08 * h):int(0.92 * h), : int(0.58 * w)]  # the blueprint's 3D view
            green = leaf_green_fraction(cloud_view)
            tint = mask_tint_fraction(shot[int(0.08 * h):int(0.5 * h), int(0.62 * w):])  # image view
            if green > 0.01 and tint > 0.01:
                break
        import cv2

        cv2.imwrite(str(tmp_path / "viewer.png"), shot)
        print(f"screenshot: {tmp_path / 'viewer.png'}")
        assert green > 0.01, f"no cloud drawn in the 3D view (leaf-green fraction {green:.4f})"
        # ... and the image view on the right shows the rectified image with the plant mask over it
        assert tint > 0.01, f"no plant mask drawn over the image (magenta fraction {tint:.4f})"
    finally:
        if browser is not None:
            browser.close()
        if view.poll() is None:
            view.send_signal(signal.SIGINT)
            try:
                view.wait(30)
            except subprocess.TimeoutExpired:
                view.kill()
                view.wait(10)
    assert view.returncode == 0, (tmp_path / "view.err").read_text()[-2000:]
    # Ctrl-C stopped the viewer server too: nothing is left listening
    gone, alive = psutil.wait_procs(servers, timeout=15)
    assert not alive, [p.cmdline() for p in alive]
