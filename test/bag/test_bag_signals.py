"""Recordings survive stops: SIGTERM/SIGHUP/SIGINT close every bag validly; SIGKILL costs at most
the last flush period; looped recording appends or splits, never overwrites."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rclpy")
rosbags = pytest.importorskip("rosbags.highlevel")

from canopy_stereo.bag import BagError, BagReader, BagWriter, repair_bag  # noqa: E402
from canopy_stereo.bag.split import split_file_path  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig  # noqa: E402
from canopy_stereo.ros.context import private_domain_id  # noqa: E402
from test.support.ros_harness import killed_at_exit  # noqa: E402

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
LEFT, RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"


def _env(domain: int | None = None) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("CANOPY_STEREO_DEBUG", None)
    if domain is not None:
        env["ROS_DOMAIN_ID"] = str(domain)
    return env


def _rosbags_reads_whole(path: Path) -> int:
    """Messages rosbags reads from ``path``; fails unless it reads exactly what the summary says."""
    with rosbags.AnyReader([path]) as reader:
        announced = sum(c.msgcount for c in reader.connections)
        n = 0
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    assert n == announced, f"{path}: rosbags read {n} of {announced} messages"
    return n


def _complete(path: Path) -> BagReader:
    bag = BagReader(path)
    check = bag.verify()
    assert check.ok, "\n".join(check.lines())
    return bag


@pytest.fixture(scope="module")
def slow_bag(tmp_path_factory) -> Path:
    """A 30 s stereo bag: the croton's 4 pairs repeated, one pair every 2 s (15 pairs)."""
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    src = BagReader(bundled_bag("croton"))
    pairs = list(zip(src.messages(LEFT), src.messages(RIGHT)))
    path = tmp_path_factory.mktemp("slow") / "slow30.mcap"
    t0 = 1_800_000_000_000_000_000
    with BagWriter(path, compression="lz4", flush_period_s=0) as w:
        for k in range(16):
            for m in pairs[k % len(pairs)]:
                msg = deserialize_message(m.data, Image)
                lag = (m.publish_time_ns - pairs[0][0].publish_time_ns) % 10_000_000  # right after left
                stamp = t0 + k * 2_000_000_000 + lag
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                w.write(m.topic, serialize_message(msg), stamp + 2_000_000, publish_time_ns=stamp,
                        msg_type=m.type_name)
    bag = BagReader(path)
    assert (bag.end_ns - bag.start_ns) / 1e9 == pytest.approx(30.0, abs=0.1)
    return path


def _run_cli(bag: Path, out: Path):
    args = [sys.executable, "-m", "canopy_stereo.cli", "run", "--bag", str(bag), "--rig",
            str(bundled_rig("croton")), "--record", str(out), "--matcher", "sgbm", "--no-segment"]
    return subprocess.Popen(args, cwd=REPO, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _wait_for_file(path: Path, proc, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, f"{path} never appeared"
        time.sleep(0.05)


def _wait_for_recorded(path: Path, proc, topics, timeout: float = 120.0) -> None:
    """Wait until a recording being written (flushed every second) holds a message on each topic."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            bag = BagReader(path)
            if set(topics) <= set(bag.topics) and all(any(True for _ in bag.messages([t])) for t in topics):
                return
        except BagError:  # not flushed yet
            pass
        assert proc.poll() is None, proc.communicate()[1]
        assert time.monotonic() < deadline, f"{path}: no message on {topics} within {timeout:g} s"
        time.sleep(0.5)


def _recorded_so_far(path: Path) -> int:
    """Messages readable in a recording still being written (flushed every second)."""
    try:
        return sum(1 for _ in BagReader(path).messages())
    except BagError:
        return 0


@pytest.mark.slow
def test_sigterm_at_three_moments_of_run_record_leaves_complete_bags(slow_bag, tmp_path):
    """SIGTERM during start-up, early and late in a 30 s `run --record` (and SIGKILL once):
    every SIGTERMed file is complete and rosbags reads it whole; the SIGKILLed one reads up
    to its last flush and repairs into a complete bag. The moments: the output file has
    just appeared; the first outputs are on disk; 15 s later with at least 6 frames recorded
    (a frame every 2 s, 4 outputs each) -- waited for, not timed, so that a slow machine
    cannot make the test meaningless."""
    names = ("startup", "early", "kill", "late")
    procs = {name: _run_cli(slow_bag, tmp_path / f"{name}.mcap") for name in names}
    paths = {name: tmp_path / f"{name}.mcap" for name in names}

    def wait_until(cond, running, timeout=90.0):
        deadline = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < deadline and all(procs[n].poll() is None for n in running), \
                {n: procs[n].poll() for n in running}
            time.sleep(0.25)

    with killed_at_exit(*procs.values()):
        for name, proc in procs.items():
            _wait_for_file(paths[name], proc)
        procs["startup"].send_signal(signal.SIGTERM)
        wait_until(lambda: _recorded_so_far(paths["early"]) > 0, ("early", "kill", "late"))
        on_disk = {"early": _recorded_so_far(paths["early"])}  # readable just before the signal
        procs["early"].send_signal(signal.SIGTERM)
        wait_until(lambda: _recorded_so_far(paths["kill"]) > 0, ("kill", "late"))
        on_disk["kill"] = _recorded_so_far(paths["kill"])
        procs["kill"].send_signal(signal.SIGKILL)
        first = time.monotonic()
        wait_until(lambda: time.monotonic() - first > 15 and _recorded_so_far(paths["late"]) >= 24,
                   ("late",))
        procs["late"].send_signal(signal.SIGTERM)
        results = {name: proc.communicate(timeout=90) for name, proc in procs.items()}
    counts = {}
    for name in ("startup", "early", "late"):
        out, err = results[name]
        assert procs[name].returncode == 130, f"{name}: exit {procs[name].returncode}\n{err}"
        assert "Traceback" not in err and "interrupted" in err, err
        path = tmp_path / f"{name}.mcap"
        bag = _complete(path)
        counts[name] = _rosbags_reads_whole(path)
        assert counts[name] == bag.message_count
    assert counts["late"] > counts["early"] >= on_disk["early"] >= 1, (counts, on_disk)
    assert procs["kill"].returncode == -signal.SIGKILL
    killed = BagReader(tmp_path / "kill.mcap")
    assert killed.truncated
    kept = sum(1 for _ in killed.messages())
    # everything readable before the SIGKILL is still there (at least one flush's worth)
    assert kept >= on_disk["kill"] >= 1, (kept, on_disk, killed.summary_text())
    repaired = tmp_path / "kill_repaired.mcap"
    repair_bag(tmp_path / "kill.mcap", repaired)
    assert _rosbags_reads_whole(repaired) == kept
    _complete(repaired)


_KILLED_WRITER = """
import os, sys, time
from canopy_stereo.bag import BagWriter
w = BagWriter(sys.argv[1], flush_period_s=0.5)
for k in range(20):
    w.write("/x", bytes(1000), 1_000_000_000 + k, msg_type="std_msgs/msg/String")
time.sleep(1.5)  # three flush periods
for k in range(20, 25):
    w.write("/x", bytes(1000), 1_000_000_000 + k, msg_type="std_msgs/msg/String")
os.kill(os.getpid(), 9)
"""


@pytest.mark.slow
def test_sigkill_loses_at_most_the_last_flush_period(tmp_path):
    """Messages written more than one flush period before a SIGKILL are in the file."""
    path = tmp_path / "killed.mcap"
    proc = subprocess.run([sys.executable, "-c", _KILLED_WRITER, str(path)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    bag = BagReader(path)
    assert bag.truncated
    assert sum(1 for _ in bag.messages()) >= 20


def _graph(args, domain):
    code = "import sys; from canopy_stereo.ros.canopy_graph import main; sys.exit(main())"
    return subprocess.Popen([sys.executable, "-c", code, "--rig", str(bundled_rig("croton")),
                             "--matcher", "sgbm", "--no-segment", *map(str, args)], cwd=REPO,
                            env=_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for_passes(proc, n: int, timeout: float = 180.0, min_span_s: float = 0.0) -> list[str]:
    """Lines of stdout until ``n`` passes of --loop have printed their summaries and at least
    ``min_span_s`` seconds passed between the first pass's line and the last one read."""
    lines, passes, first = [], 0, None
    deadline = time.monotonic() + timeout
    while passes < n or time.monotonic() - first < min_span_s:
        assert time.monotonic() < deadline, "\n".join(lines)
        line = proc.stdout.readline()
        assert line or proc.poll() is None, proc.stderr.read()
        lines.append(line)
        if line.startswith("frames in:"):
            passes += 1
            first = time.monotonic() if first is None else first
    return lines


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGHUP, signal.SIGINT])
def test_graph_loop_record_appends_every_pass_and_closes_on_signals(tmp_path, sig):
    """`canopy_graph --loop --record` keeps every pass in one file (no overwrite); SIGHUP or
    SIGINT close it validly."""
    out = tmp_path / "loop.mcap"
    proc = _graph(["--bag", bundled_bag("croton"), "--rate", "0", "--loop", "--record", out],
                  private_domain_id())
    with killed_at_exit(proc):
        _wait_for_passes(proc, 3)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    bag = _complete(out)
    clouds = bag.topics["/stereo/points2"].message_count
    assert clouds > 4, bag.summary_text()  # more than one pass of 4 frames: passes append
    assert _rosbags_reads_whole(out) == bag.message_count


@pytest.mark.slow
def test_graph_loop_record_splits_like_rosbag2(tmp_path):
    """--split-duration rotates to <name>_0.mcap, <name>_1.mcap, ...: each a complete bag;
    together they hold every message once."""
    out = tmp_path / "split.mcap"
    proc = _graph(["--bag", bundled_bag("croton"), "--rate", "2", "--loop", "--record", out,
                   "--split-duration", "0.6"], private_domain_id())
    with killed_at_exit(proc):
        # one graph loops the 0.3 s bag: at rate 2 three passes take ~0.45 s, less than one split
        # duration; run until the outputs span more than two
        _wait_for_passes(proc, 3, min_span_s=1.5)
        proc.send_signal(signal.SIGTERM)
        stdout, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert not out.exists()
    files = sorted(tmp_path.glob("split_*.mcap"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))
    assert len(files) >= 2 and files[0] == split_file_path(out, 0), files
    stamps = []
    for f in files:
        bag = _complete(f)
        _rosbags_reads_whole(f)
        times = [m.log_time_ns for m in bag.messages()]
        assert times and times[-1] - times[0] < 0.6e9 + 1, f
        stamps += [(m.topic, m.publish_time_ns, m.log_time_ns) for m in bag.messages()]
    assert len(stamps) == len(set(stamps))
    assert f"recorded {files[0]}" in stdout or str(files[0]) in stdout


def test_split_size_names_files_like_rosbag2(tmp_path):
    import numpy as np
    from std_msgs.msg import String

    rng = np.random.default_rng(5)
    out = tmp_path / "sized.mcap"
    with BagWriter(out, split_size=50_000, chunk_size=10_000, flush_period_s=0) as w:
        for k in range(30):
            text = "".join(chr(c) for c in rng.integers(33, 127, 5000))  # incompressible
            w.write("/x", String(data=text), 1_000 + k)
    assert [p.name for p in w.paths] == [f"sized_{i}.mcap" for i in range(len(w.paths))]
    assert len(w.paths) >= 3
    total = 0
    for p in w.paths:
        assert p.stat().st_size < 50_000 + 20_000
        total += _complete(p).message_count
        _rosbags_reads_whole(p)
    assert total == 30


@pytest.mark.slow
def test_graph_cameras_record_closes_on_sigterm(tmp_path):
    """`canopy_graph --cameras ... --record --traits` (live capture, image sequences standing in for
    webcams): SIGTERM leaves a complete bag that rosbags reads whole, the live traits in it."""
    import cv2

    reader = BagReader(bundled_bag("croton"))
    from canopy_stereo.ros.convert import msg_to_image

    for side in ("left", "right"):
        for k, (_, m) in enumerate(reader.read(f"/stereo/{side}/image_raw")):
            cv2.imwrite(str(tmp_path / f"{side}_{k:03d}.png"), msg_to_image(m))
    out = tmp_path / "live.mcap"
    traits = ("/stereo/traits", "/stereo/traits/markers")
    proc = _graph(["--cameras", tmp_path / "left_%03d.png", tmp_path / "right_%03d.png", "--fps", "5",
                   "--record", out, "--traits"], private_domain_id())
    with killed_at_exit(proc):
        _wait_for_file(out, proc)
        # the periodic flush makes the recording readable while it runs
        _wait_for_recorded(out, proc, ("/stereo/points2", *traits))
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    bag = _complete(out)
    # every recorded left frame is one of the camera's, pixel for pixel
    frames = [msg_to_image(m) for _, m in reader.read("/stereo/left/image_raw")]
    recorded = [msg_to_image(m) for _, m in bag.read("/stereo/left/image_raw")]
    assert len(recorded) == bag.topics["/stereo/left/image_raw"].message_count >= 1
    assert all(any(np.array_equal(r, f) for f in frames) for r in recorded)
    # --traits: the live traits are recorded too (JSON and markers, read by rosbags below)
    assert {t: bag.topics[t].type_name for t in traits} == {
        "/stereo/traits": "std_msgs/msg/String", "/stereo/traits/markers": "visualization_msgs/msg/MarkerArray"}
    assert all(bag.topics[t].message_count >= 1 for t in traits), bag.summary_text()
    report = json.loads(next(m for _, m in bag.read("/stereo/traits")).data)["report"]
    assert 300 < report["canopy"]["height"] < 600  # mm: the croton stands about 45 cm tall
    assert _rosbags_reads_whole(out) == bag.message_count


_INTERRUPTED_WRITERS = """
import signal, sys
from pathlib import Path
from std_msgs.msg import String
from rclpy.serialization import serialize_message
from canopy_stereo.bag import BagWriter

raw = serialize_message(String(data="x" * 1000))


def interrupt(*_):
    raise KeyboardInterrupt

signal.signal(signal.SIGALRM, interrupt)
out = Path(sys.argv[1])
for i in range(int(sys.argv[2])):
    signal.setitimer(signal.ITIMER_REAL, 0.0001 + i * 0.00015)  # lands somewhere else each time
    try:
        w = BagWriter(out / f"b{i}.mcap", flush_period_s=0.001)
        for k in range(200):
            w.write("/s", raw, 1000 + k, msg_type="std_msgs/msg/String")
        w.close()
    except KeyboardInterrupt:
        pass
    signal.setitimer(signal.ITIMER_REAL, 0)
"""


@pytest.mark.slow
def test_an_interrupt_at_any_moment_of_a_writer_leaves_a_complete_file(tmp_path):
    """KeyboardInterrupt (what SIGINT/SIGTERM/SIGHUP become) at 40 different instants of
    create/write/close: every file is a complete bag (opening, closing and rotating are not
    interruptible; a writer orphaned by the interrupt is completed at exit)."""
    n = 40
    proc = subprocess.run([sys.executable, "-c", _INTERRUPTED_WRITERS, str(tmp_path), str(n)],
                          cwd=REPO, env=_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    files = sorted(tmp_path.glob("b*.mcap"))  # (an interrupt before the file was created: none)
    counts = []
    for f in files:
        check = BagReader(f).verify()
        assert check.ok, "\n".join(check.lines())
        counts.append(sum(check.messages_recovered.values()))
    assert len(files) > n // 2 and len(set(counts)) > 3, counts  # interrupted at many stages
