"""Shared fixtures: repository paths, the paper rig, ../shared/data, CLI runner, ROS harnesses."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The checkout's root folder."""
    return REPO


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the checkout (CI has it; a user's clone may not: skip)."""
    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not beside this checkout")
    return SHARED_DATA


@pytest.fixture(scope="session")
def paper_rig():
    """The paper's rig (config/paper_rig.yaml), 640x480, millimetres."""
    from canopy_stereo.io.rig import load_rig

    return load_rig(REPO / "config" / "paper_rig.yaml")


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def run_cli_subprocess(*args, cwd=None, timeout=300):
    """Run ``python -m canopy_stereo.cli ARGS`` in a fresh process; returns CompletedProcess."""
    env = dict(os.environ)
    env.pop("CANOPY_STEREO_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "canopy_stereo.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd or REPO, timeout=timeout, env=env)


@pytest.fixture
def cli():
    """Run the CLI in-process: ``cli("reconstruct", ...) -> (exit_code, stdout, stderr)``."""
    import contextlib
    import io

    from canopy_stereo.cli import main

    def _run(*args):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main([str(a) for a in args])
            except SystemExit as exc:  # argparse errors
                code = exc.code
        return code, out.getvalue(), err.getvalue()

    return _run


@pytest.fixture
def ros_processes(tmp_path):
    """A :class:`ros_harness.ProcessGroup` on this test process's private DDS domain: start
    node executables in processes of their own; all are stopped after the test (their
    logs are in ``tmp_path / "logs"``)."""
    pytest.importorskip("rclpy")
    from canopy_stereo.ros.context import private_domain_id
    from test.support.ros_harness import ProcessGroup

    group = ProcessGroup(private_domain_id(), tmp_path / "logs")
    try:
        yield group
    finally:
        group.stop_all()


@pytest.fixture
def harness():
    """The one in-process spin harness (:class:`test.support.ros_harness.Harness`): an rclpy
    context on this test process's private DDS domain, a helper node ``/stereo/test_helper``
    (``publisher``, ``collect``, ``connect``) and every node ``harness.add``-ed, spun by one
    executor in a background thread; all nodes destroyed and the context shut down after the
    test."""
    pytest.importorskip("rclpy")
    from canopy_stereo.ros.context import ros_context
    from test.support.ros_harness import Harness

    with ros_context() as ctx:
        h = Harness(ctx)
        try:
            yield h
        finally:
            h.close()
