"""Every bad file, in every executable that takes it: exit status 2 and one line, no traceback.

Parameter files (``--ros-args --params-file``) and rig files (``--rig``, ``rig_file``, a rig
given with ``--params-file``): malformed YAML, not UTF-8, list-shaped, missing, unreadable (a
directory: the tests run as root, for whom file permissions do not apply), a mixed-type list
rcl refuses, a number written as a string (refused everywhere). The matrix runs the
executables' ``main`` in one helper process (test/support/run_mains.py); a few real processes
show the same from the console scripts, plus camera_node with a broken rig and bag_record on a
full disk.
"""
from __future__ import annotations

import json
import resource
import signal
import subprocess
import sys
import time

import pytest

from canopy_stereo.errors import CanopyStereoError, RigError
from test.conftest import REPO

pytest.importorskip("rclpy")

RIG = REPO / "config" / "croton_rig.yaml"
BAG = REPO / "bags" / "croton.mcap"

#: executable -> (module, arguments before --ros-args)
EXECUTABLES = {
    "camera_node": ("canopy_stereo.ros.nodes.camera", []),
    "rectify_node": ("canopy_stereo.ros.nodes.rectify", []),
    "disparity_node": ("canopy_stereo.ros.nodes.disparity", []),
    "segment_node": ("canopy_stereo.ros.nodes.segment", []),
    "point_cloud_node": ("canopy_stereo.ros.nodes.point_cloud", []),
    "fusion_node": ("canopy_stereo.ros.fusion_node", []),
    "bag_record": ("canopy_stereo.ros.recorder", ["-o", "{tmp}/never.mcap", "-a"]),
    "bag_play": ("canopy_stereo.ros.player", [str(BAG)]),
    "canopy_graph": ("canopy_stereo.ros.canopy_graph", ["--rig", str(RIG), "--bag", str(BAG)]),
}

#: executables that take a rig file, and how: argv after the executable's name
RIG_USES = {
    "rectify_node --params-file": ("canopy_stereo.ros.nodes.rectify", ["--ros-args", "--params-file", "{rig}"]),
    "rectify_node rig_file": ("canopy_stereo.ros.nodes.rectify", ["--ros-args", "-p", "rig_file:={rig}"]),
    "camera_node --params-file": ("canopy_stereo.ros.nodes.camera",
                                  ["--ros-args", "-p", "device:=/nonexistent", "--params-file", "{rig}"]),
    "camera_node rig_file": ("canopy_stereo.ros.nodes.camera",
                             ["--ros-args", "-p", "device:=/nonexistent", "-p", "rig_file:={rig}"]),
    "bag_record --rig": ("canopy_stereo.ros.recorder", ["-o", "{tmp}/never.mcap", "-a", "--rig", "{rig}"]),
    "canopy_graph --rig": ("canopy_stereo.ros.canopy_graph", ["--rig", "{rig}", "--bag", str(BAG)]),
    "canopy-stereo run --rig": ("canopy_stereo.cli", ["run", "--bag", str(BAG), "--rig", "{rig}"]),
}


def bad_files(tmp) -> dict:
    """name -> path of each kind of bad parameter/rig file (and what its one line must say)."""
    good = RIG.read_text(encoding="utf-8")
    files = {
        "malformed": ("a: [1, 2\n", "not valid YAML"),
        "non_utf8": (b"\xff\xfe/**:\n  ros__parameters:\n    x: 1\n", "not UTF-8"),
        "list_shaped": ("- 1\n- 2\n", "list"),
        "mixed_list": (good.replace("D_left: [0.0, 0.0,", "D_left: [0.0, 'a',"), "same type"),
        "number_as_string": (good.replace("image_width: 640", 'image_width: "640"'), "image_width"),
    }
    out = {}
    for name, (content, says) in files.items():
        path = tmp / f"{name}.yaml"
        (path.write_bytes if isinstance(content, bytes) else path.write_text)(content)
        out[name] = (path, says)
    out["missing"] = (tmp / "missing.yaml", "No such file")
    (tmp / "a_directory").mkdir()
    out["unreadable"] = (tmp / "a_directory", "Is a directory")
    return out


def run_mains(calls: list, tmp) -> list[dict]:
    """``main(argv)`` of each ``(module, argv)`` in one helper process (test/support/run_mains.py)."""
    spec = tmp / "calls.json"
    spec.write_text(json.dumps(calls))
    proc = subprocess.run([sys.executable, "-m", "test.support.run_mains", str(spec)], cwd=REPO,
                          capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.strip()]


def assert_one_line(result: dict, says: str, label: str) -> None:
    lines = _lines(result["output"])
    assert result["status"] == 2, (label, result)
    assert len(lines) == 1, (label, result["output"])
    assert "Traceback" not in result["output"] and says in lines[0], (label, lines)


# ---------------------------------------------------------------------------------- in-process


@pytest.mark.parametrize("kind", ["malformed", "non_utf8", "list_shaped", "missing", "unreadable"])
def test_check_parameter_file_names_the_problem_in_one_line(tmp_path, kind):
    from canopy_stereo.ros.params import check_parameter_file

    path, says = bad_files(tmp_path)[kind]
    with pytest.raises(CanopyStereoError) as err:
        check_parameter_file(path)
    assert says in str(err.value) and str(path) in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("kind", ["malformed", "non_utf8", "list_shaped", "missing", "unreadable",
                                  "number_as_string"])
def test_load_rig_names_the_problem_in_one_line(tmp_path, kind):
    from canopy_stereo.io.rig import load_rig

    path, says = bad_files(tmp_path)[kind]
    with pytest.raises(RigError) as err:
        load_rig(path)
    assert says in str(err.value) and "\n" not in str(err.value)


def test_a_good_parameter_file_passes_and_rcl_refusals_become_one_line(tmp_path):
    from rclpy.context import Context

    from canopy_stereo.ros.context import init_ros
    from canopy_stereo.ros.params import check_parameter_file, parameter_files

    check_parameter_file(RIG)
    assert parameter_files(["x", "--ros-args", "--params-file", "a", "-p", "b:=1", "--", "--params-file",
                            "c", "--ros-args", "--params-file", "d"]) == ["a", "d"]
    path, _ = bad_files(tmp_path)["mixed_list"]
    with pytest.raises(CanopyStereoError, match=r"^parameter file .*mixed_list.yaml: Sequence should be of same "
                                                 r"type[^\n]*$"):
        init_ros(["x", "--ros-args", "--params-file", str(path)], context=Context())
    with pytest.raises(CanopyStereoError, match=r"^invalid --ros-args parameter override rule '-p foo'"):
        init_ros(["x", "--ros-args", "-p", "foo"], context=Context())


# ---------------------------------------------------------------------------------- executables


@pytest.mark.ros
@pytest.mark.slow
def test_every_executable_refuses_every_bad_params_file_in_one_line(tmp_path):
    """9 executables x 7 bad parameter files: exit 2, one line naming the file, no traceback."""
    files = bad_files(tmp_path)
    calls, labels = [], []
    for exe, (module, args) in EXECUTABLES.items():
        for kind, (path, says) in files.items():
            if kind == "number_as_string":
                continue  # a valid parameter file: the rig tests below
            argv = [exe] + [a.format(tmp=tmp_path) for a in args] + ["--ros-args", "--params-file", str(path)]
            calls.append([module, argv])
            labels.append((f"{exe} {kind}", says if kind != "mixed_list" else "same type"))
    for result, (label, says) in zip(run_mains(calls, tmp_path), labels):
        assert_one_line(result, says, label)


@pytest.mark.ros
@pytest.mark.slow
def test_every_executable_refuses_every_bad_rig_file_in_one_line(tmp_path):
    """Rig files given every way an executable takes one: exit 2, one line, no traceback; a
    number written as a string is refused everywhere (camera_node too: a broken rig is an error,
    not "no camera_info")."""
    files = bad_files(tmp_path)
    calls, labels = [], []
    for use, (module, args) in RIG_USES.items():
        for kind, (path, says) in files.items():
            if kind == "mixed_list" and "--params-file" not in use:
                says = "D_left"  # read by the package's own reader: refused as not numbers
            argv = [use.split()[0]] + [a.format(tmp=tmp_path, rig=path) for a in args]
            if module == "canopy_stereo.cli":
                argv = argv[1:]
            calls.append([module, argv])
            labels.append((f"{use} {kind}", says))
    for result, (label, says) in zip(run_mains(calls, tmp_path), labels):
        assert_one_line(result, says, label)


@pytest.mark.ros
@pytest.mark.slow
@pytest.mark.parametrize("exe, kind", [("rectify_node", "malformed"), ("bag_play", "non_utf8"),
                                       ("canopy_graph", "list_shaped"), ("camera_node", "number_as_string")])
def test_console_scripts_exit_2_with_one_line(tmp_path, exe, kind):
    """The installed executables themselves (a process each): status 2, one line on the console."""
    from test.support.ros_harness import executable_command

    path, says = bad_files(tmp_path)[kind]
    module, args = EXECUTABLES[exe]
    args = [a.format(tmp=tmp_path) for a in args]
    if exe == "camera_node":
        args += ["--ros-args", "-p", "device:=/nonexistent"]
    else:
        args += ["--ros-args"]
    proc = subprocess.run(executable_command(exe) + args + ["--params-file", str(path)], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, out
    assert len(_lines(out)) == 1 and says in out and "Traceback" not in out, out


@pytest.mark.ros
@pytest.mark.slow
def test_bag_record_on_a_full_disk_ends_with_one_line(tmp_path):
    """The bag's file may not grow past 200 kB (RLIMIT_FSIZE: the writes fail as on a full disk)
    while 640x480 images arrive: bag_record prints its one error line and exits 2; closing the
    recorder, which fails the same way, adds nothing."""
    import numpy as np
    from sensor_msgs.msg import Image

    from canopy_stereo.ros.context import private_domain_id
    from canopy_stereo.ros.convert import image_to_msg
    from test.support.ros_harness import Probe, executable_command, killed_at_exit

    def small_files():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))

    domain = private_domain_id()
    env = {**__import__("os").environ, "ROS_DOMAIN_ID": str(domain),
           "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    out = tmp_path / "full.mcap"
    proc = subprocess.Popen(executable_command("bag_record") + ["/stereo/left/image_raw", "-o", str(out),
                                                                "--compression", "none", "--max-duration", "60"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            preexec_fn=small_files)
    probe = Probe(domain)
    with killed_at_exit(proc):
        try:
            pub = probe.publisher(Image, "left/image_raw")
            img = np.random.default_rng(1).integers(0, 255, (480, 640, 3), dtype=np.uint8)
            deadline = time.monotonic() + 60
            while proc.poll() is None and time.monotonic() < deadline:
                pub.publish(image_to_msg(img, "bgr8", stamp_ns=time.time_ns(), frame_id="left"))
                time.sleep(0.1)
            output = proc.communicate(timeout=30)[0]
        finally:
            probe.close()
    lines = [line for line in _lines(output) if "bag_record" in line or "Traceback" in line]
    assert proc.returncode == 2, output
    assert "Traceback" not in output, output
    assert lines[-1].startswith("bag_record: error: cannot write bag") and len(
        [line for line in lines if "error" in line]) == 1, output
