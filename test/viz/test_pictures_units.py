"""Pictures that explain themselves (colour bars, units) and PLY units stated in the file."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.io.ply import read_ply, write_ply
from canopy_stereo.viz.colour import COLORMAP, colorize, depth_picture, disparity_picture, picture_offset


def test_ply_states_its_unit_in_words_and_old_files_still_read(tmp_path):
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    path = write_ply(tmp_path / "c.ply", pts, unit="mm")
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "comment unit mm" in header and "comment x y z in millimetres" in header
    # a file of an earlier version (metres, the machine-readable comment only) still reads
    old = tmp_path / "old.ply"
    old.write_bytes(b"ply\nformat binary_little_endian 1.0\ncomment unit m\ncomment generator canopy_stereo\n"
                    b"element vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
                    + pts.astype("<f4").tobytes())
    cloud = read_ply(old)
    assert cloud.unit == "m" and np.allclose(cloud.points, pts)


def test_reconstruct_writes_millimetres_whatever_the_rig_unit(tmp_path, cli, paper_rig):
    """The same pair through the paper rig in mm and rescaled to metres gives the same mm PLY."""
    import cv2

    from canopy_stereo.io.rig import Rig, save_rig
    from canopy_stereo.sim import render_scene

    sim = render_scene("croton", paper_rig, seed=0)
    cv2.imwrite(str(tmp_path / "l.png"), sim.left)
    cv2.imwrite(str(tmp_path / "r.png"), sim.right)
    rig_m = Rig(P_left=paper_rig.P_left @ np.diag([1000.0, 1000.0, 1000.0, 1.0]),
                P_right=paper_rig.P_right @ np.diag([1000.0, 1000.0, 1000.0, 1.0]),
                image_size=paper_rig.image_size, world_unit="m", extra=dict(paper_rig.extra))
    save_rig(paper_rig, tmp_path / "mm.yaml")
    save_rig(rig_m, tmp_path / "m.yaml")
    for name in ("mm", "m"):
        code, _, err = cli("reconstruct", tmp_path / "l.png", tmp_path / "r.png", "--rig",
                           tmp_path / f"{name}.yaml", "-o", tmp_path / f"{name}.ply")
        assert code == 0, err
    a, b = read_ply(tmp_path / "mm.ply"), read_ply(tmp_path / "m.ply")
    assert a.unit == b.unit == "mm" and len(a) > 10_000
    assert abs(len(a) - len(b)) < 0.01 * len(a)
    assert np.allclose(np.median(a.points, axis=0), np.median(b.points, axis=0), atol=1.0)


def test_disparity_and_depth_pictures_have_a_colour_bar_with_units():
    d = np.tile(np.linspace(10, 50, 320, dtype=np.float32), (240, 1))
    d[:20, :20] = np.nan
    pic = disparity_picture(d, title="disparity")
    y0, x0 = picture_offset(d.shape)
    assert pic.shape[0] == 240 + y0 + 6 and pic.shape[1] > 320 + 40
    body = pic[y0:y0 + 240, x0:x0 + 320]
    assert np.all(body[:20, :20] == 0)  # invalid: black
    # the map is the package's colour map: low disparity blue-ish at the left, high red at the right
    assert np.array_equal(body[120:121, 100:101], colorize(d[120:121, 100:101], lo=np.nanpercentile(d, 1),
                                                           hi=np.nanpercentile(d, 99)))
    assert body[120, 315, 2] > body[120, 315, 0] and body[120, 5, 0] > body[120, 5, 2]
    # the bar: the column right of the picture runs from the top value (red) to the bottom (blue)
    bar = pic[y0:y0 + 240, 320 + 8 + 5]
    assert bar[2, 2] > bar[2, 0] and bar[-3, 0] > bar[-3, 2]
    # units and title are drawn (dark text pixels above the bar and in the title strip)
    assert (pic[:y0 - 2, 320:] < 100).any() and (pic[:y0 - 2, :200] < 100).any()
    z = depth_picture(1.0 / d, unit="m")
    assert z.shape == pic.shape
    # the colour map is OpenCV's turbo, value for value: colorize maps lo..hi onto its 256 entries
    import cv2

    assert COLORMAP == cv2.COLORMAP_TURBO
    ramp = np.arange(256, dtype=np.uint8)[None]
    assert np.array_equal(colorize(ramp.astype(float), lo=0, hi=255), cv2.applyColorMap(ramp, cv2.COLORMAP_TURBO))


def test_progress_only_on_a_terminal():
    import io

    from canopy_stereo.progress import Progress

    log = io.StringIO()  # not a TTY: logs and CI stay quiet
    with Progress(3, "view", stream=log) as bar:
        for name in "abc":
            bar.step(name)
    assert log.getvalue() == ""

    class Tty(io.StringIO):
        def isatty(self):
            return True

    term = Tty()
    with Progress(3, "view", stream=term) as bar:
        bar.step("a")
        assert "view 1/3" in term.getvalue() and ": a" in term.getvalue()
        bar.step("b")
    assert "view 2/3" in term.getvalue() and term.getvalue().endswith("\r")


@pytest.mark.slow
def test_first_run_says_it_is_compiling_and_how_long(tmp_path):
    """A fresh numba cache (as on a new installation): the warm-up says what it does and
    how long it took; the next process loads the cache and says nothing."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    code = "from canopy_stereo.cli.progress import warm_up_kernels; warm_up_kernels(say_after_s=0.5)"
    first = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=600)
    assert first.returncode == 0, first.stderr
    lines = first.stderr.strip().splitlines()
    assert lines[0].startswith("preparing the numba kernels") and "first run only" in lines[0]
    assert lines[-1].startswith("compiled ") and " kernels in " in lines[-1] and "cached" in lines[-1]
    second = subprocess.run([sys.executable, "-c", code.replace("0.5", "60")], capture_output=True,
                            text=True, env=env, timeout=600)
    assert second.returncode == 0 and second.stderr.strip() == "", second.stderr
