"""Bad options of calibrate, measure, simulate and run: one readable line, exit status 2.

Each case is a value a user can type that the commands used to accept silently (or turn
into "internal error"); the command must refuse it before doing any work.
"""
import sys

import numpy as np
import pytest

from test.conftest import REPO, run_cli_subprocess


def _rig_with(tmp_path, name, **extra):
    text = (REPO / "config" / "croton_rig.yaml").read_text()
    lines = [ln for ln in text.splitlines() if ln.split(":")[0].strip() not in extra]
    lines += [f"    {k}: {v}" for k, v in extra.items()]
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture
def files(tmp_path):
    import cv2

    png = tmp_path / "left.png"
    cv2.imwrite(str(png), np.zeros((48, 64, 3), np.uint8))
    org = tmp_path / "org.npy"
    np.save(org, np.zeros((6, 8, 3), np.float32))
    cplx = tmp_path / "complex.npy"
    np.save(cplx, np.zeros((6, 8, 3), complex))
    csv = tmp_path / "nan.csv"
    csv.write_text("X,Y,Z,u_left,v_left,u_right,v_right\n" + "1,2,3,4,5,6,7\n" * 6 + "1,2,nan,4,5,6,7\n")
    return {"png": png, "org": org, "csv": csv, "cplx": cplx, "tmp": tmp_path}


CASES = {
    # calibrate
    "calibrate-points-png": (["calibrate", "--points", "{png}", "-o", "{tmp}/r.yaml"], "not a text CSV"),
    "calibrate-points-nan": (["calibrate", "--points", "{csv}", "-o", "{tmp}/r.yaml"], "non-finite"),
    "calibrate-unit": (["calibrate", "--points", "{csv}", "--unit", "furlong", "-o", "{tmp}/r.yaml"],
                       "--unit must be one of m, cm, mm"),
    "calibrate-square": (["calibrate", "--chessboard", "a*.png", "b*.png", "--square", "nan", "-o",
                          "{tmp}/r.yaml"], "--square"),
    "calibrate-pattern": (["calibrate", "--chessboard", "a*.png", "b*.png", "--pattern", "1x6", "-o",
                           "{tmp}/r.yaml"], "--pattern"),
    "calibrate-image-size": (["calibrate", "--points", "{csv}", "--image-size", "0x480", "-o",
                              "{tmp}/r.yaml"], "--image-size"),
    # measure
    "measure-unit": (["measure", "{org}", "--unit", "furlong", "-o", "{tmp}/r.json"], "--unit must be one of"),
    "measure-voxel": (["measure", "{org}", "--voxel", "inf", "-o", "{tmp}/r.json"], "--voxel"),
    "measure-ground": (["measure", "{org}", "--ground", "0,0,0,1", "-o", "{tmp}/r.json"], "non-zero normal"),
    "measure-complex": (["measure", "{cplx}", "-o", "{tmp}/r.json"], "must hold real coordinates"),
    "measure-min-leaf": (["measure", "{org}", "--min-leaf-pixels", "0", "-o", "{tmp}/r.json"],
                         "--min-leaf-pixels"),
    # simulate
    "simulate-views-0": (["simulate", "croton", "-o", "{tmp}/s", "--views", "0"], "--views must be at least 1"),
    "simulate-views-neg": (["simulate", "croton", "-o", "{tmp}/s", "--views", "-2"], "--views"),
    "simulate-supersample": (["simulate", "croton", "-o", "{tmp}/s", "--supersample", "0"], "--supersample"),
    "simulate-elevation": (["simulate", "croton", "-o", "{tmp}/s", "--views", "3", "--orbit", "--elevation",
                            "95"], "--elevation"),
    # run (nothing is started: the options and the rig are checked first)
    "run-disp-max": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig", "{rig_neg}"],
                     "disp_max (-5) must be greater than disp_min (12)"),
    "run-disp-min-neg": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig", "{rig_min_neg}"],
                         "disp_min must be >= 0 pixels, got -3"),
    "run-disp-text": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig", "{rig_text}"],
                      "disp_min must be a whole number"),
    "run-rate": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig", str(REPO / "config/croton_rig.yaml"),
                  "--rate", "nan"], "--rate"),
    "run-in-flight": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig",
                       str(REPO / "config/croton_rig.yaml"), "--max-in-flight", "0"], "--max-in-flight"),
    "run-domain": (["run", "--bag", str(REPO / "bags/croton.mcap"), "--rig", str(REPO / "config/croton_rig.yaml"),
                    "--domain-id", "500"], "--domain-id"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_option_is_one_line_exit_2(cli, files, tmp_path, case):
    argv, message = CASES[case]
    names = {k: str(v) for k, v in files.items()}
    if case.startswith("run-disp"):
        names["rig_neg"] = str(_rig_with(tmp_path, "neg.yaml", disp_max=-5))
        names["rig_text"] = str(_rig_with(tmp_path, "text.yaml", disp_min="near"))
        names["rig_min_neg"] = str(_rig_with(tmp_path, "minneg.yaml", disp_min=-3))
    argv = [a.format(**names) for a in argv]
    code, out, err = cli(*argv)
    assert code == 2, (out, err)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert message in lines[0] and "internal error" not in err and "Traceback" not in err
    assert not (tmp_path / "s").exists()  # simulate refused before writing anything


@pytest.mark.slow
def test_calibrate_png_as_points_in_a_fresh_process(files):
    """The reported case end to end: the console script's process, not only main()."""
    res = run_cli_subprocess("calibrate", "--points", files["png"], "-o", files["tmp"] / "r.yaml")
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "not a text CSV" in lines[0] and str(files["png"]) in lines[0]


def test_reconstruct_and_disparity_node_share_the_range_check(cli, tmp_path, files):
    """One owner (disparity_range_for): reconstruct refuses the rig run refuses, and so does
    disparity_node given the same rig file's values as parameters."""
    import cv2

    rig = _rig_with(tmp_path, "neg.yaml", disp_max=-5)
    img = tmp_path / "full.png"
    cv2.imwrite(str(img), np.zeros((480, 640, 3), np.uint8))
    code, _, err = cli("reconstruct", img, img, "--rig", rig, "-o", tmp_path / "c.ply")
    assert code == 2 and "disp_max (-5) must be greater than disp_min (12)" in err
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.context import ros_context
    from canopy_stereo.ros.nodes.disparity import DisparityNode
    from canopy_stereo.ros.params import rig_parameter_overrides

    with ros_context() as ctx:
        overrides = rig_parameter_overrides(load_rig(rig)) + [Parameter("matcher", value="sgbm")]
        with pytest.raises(CanopyStereoError, match=r"disp_max out of range. Min: -1"):
            DisparityNode(context=ctx, parameter_overrides=overrides, start_parameter_services=False)


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="address-space limit via setrlimit")
def test_a_rig_too_large_for_memory_is_one_line_not_an_internal_error(tmp_path):
    import resource
    import subprocess

    rig = tmp_path / "huge.yaml"
    rig.write_text((REPO / "config" / "paper_rig.yaml").read_text()
                   .replace("image_width: 640", "image_width: 40000")
                   .replace("image_height: 480", "image_height: 30000"))

    def limit():  # 8 GB of address space: the 40000x30000 render cannot fit
        resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))

    res = subprocess.run([sys.executable, "-m", "canopy_stereo.cli", "simulate", "croton", "--rig", str(rig),
                          "-o", str(tmp_path / "s")], capture_output=True, text=True, timeout=300,
                         preexec_fn=limit, cwd=REPO)
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert res.returncode == 2 and len(lines) == 1, res.stderr
    assert "error: not enough memory" in lines[0] and "internal error" not in lines[0]


@pytest.mark.parametrize("argv", [
    ["run", "--bag", "{tmp}/cut.mcap", "--rig", "{rig}"],
    ["disparity", "{tmp}/missing.png", "{png}", "-o", "{tmp}/d.pfm"],
    ["reconstruct", "--rig", "{rig}", "{tmp}/missing.png", "{png}", "-o", "{tmp}/c.ply"],
])
def test_bad_input_fails_before_the_kernels_are_prepared(cli, files, monkeypatch, argv):
    """On a fresh machine preparing the numba kernels prints a progress line and takes up to a
    minute: a command with a bad input must fail before that, in one line."""
    from canopy_stereo.cli import progress

    def too_early(*args, **kwargs):
        raise AssertionError("kernels prepared before the input was checked")

    monkeypatch.setattr(progress, "warm_up_kernels", too_early)
    tmp = files["tmp"]
    (tmp / "cut.mcap").write_bytes((REPO / "bags" / "croton.mcap").read_bytes()[:200])
    args = [a.format(tmp=tmp, png=files["png"], rig=REPO / "config" / "croton_rig.yaml") for a in argv]
    if argv[0] == "run":
        pytest.importorskip("rclpy")
    code, _, err = cli(*args)
    assert code == 2 and err.count("\n") == 1, err
