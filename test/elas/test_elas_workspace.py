"""ELAS reuses its intermediate arrays from frame to frame (canopy_stereo.elas.workspace):
the results must not depend on it, must never alias it, and concurrent runs in
different threads must not share it."""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from canopy_stereo.elas import descriptor, grid, postprocess
from canopy_stereo.elas.core import elas_run
from canopy_stereo.elas.params import make_params
from canopy_stereo.elas.workspace import Workspace, thread_workspace
from canopy_stereo.io.images import read_image

REPO = Path(__file__).resolve().parents[2]
FIELDS = ("disp_left", "disp_right", "support", "triangles_left", "triangles_right")


@pytest.fixture(scope="module")
def pairs():
    """Two different real crops of the Plants pair (grey, 320x240)."""
    left = read_image(REPO / "examples" / "plants" / "left.png", color=False)
    right = read_image(REPO / "examples" / "plants" / "right.png", color=False)
    return [(np.ascontiguousarray(left[y:y + 240, x:x + 320]),
             np.ascontiguousarray(right[y:y + 240, x:x + 320]))
            for y, x in ((120, 240), (200, 300))]


def snapshot(result):
    return {name: None if getattr(result, name) is None else getattr(result, name).copy()
            for name in FIELDS}


def same(a, b) -> bool:
    return all((a[n] is None and b[n] is None) or
               (a[n].dtype == b[n].dtype and a[n].shape == b[n].shape
                and a[n].tobytes() == b[n].tobytes()) for n in FIELDS)


def test_workspace_reuses_arrays_by_name_shape_and_dtype():
    ws = Workspace()
    a = ws.array("x", (4, 5), np.float32)
    assert ws.array("x", (4, 5), np.float32) is a
    assert ws.array("x", (4, 6), np.float32) is not a          # new shape: new array
    b = ws.array("x", (4, 6), np.int32)
    assert b.dtype == np.int32 and b.flags.c_contiguous
    left, right = ws.scoped("left"), ws.scoped("right")
    assert left.array("x", (3,), np.uint8) is not right.array("x", (3,), np.uint8)
    assert left.array("x", (3,), np.uint8) is ws.scoped("left").array("x", (3,), np.uint8)
    assert ws.nbytes() == 4 * 6 * 4 + 3 + 3
    ws.clear()
    assert ws.nbytes() == 0


@pytest.mark.parametrize("preset,extra", [("robotics", {}), ("middlebury", {"subpixel": True}),
                                          ("robotics", {"subsampling": True})])
def test_results_do_not_alias_the_workspace(pairs, preset, extra):
    """A result stays what it was when later runs (other images) reuse the workspace."""
    p = make_params(preset, disp_min=0, disp_max=100, **extra)
    first = elas_run(*pairs[0], p, want_right=True)
    kept = snapshot(first)
    second = elas_run(*pairs[1], p, want_right=True)
    assert same(snapshot(first), kept)
    assert not same(snapshot(second), kept)
    # and the same images give the same result again
    assert same(snapshot(elas_run(*pairs[0], p, want_right=True)), kept)
    held = thread_workspace()
    assert held.nbytes() > 10 * first.disp_left.nbytes      # the maps are kept there
    for name in FIELDS:
        arr = getattr(first, name)
        if arr is not None:
            assert not any(np.shares_memory(arr, w) for w in held.arrays())


def test_stage_functions_give_the_same_with_and_without_a_workspace(pairs, rng):
    gl, _ = pairs[0]
    ws = Workspace()
    fresh = descriptor.compute_descriptors(gl)
    # a dirty workspace: every array full of garbage first
    for arr in (ws.array("desc", gl.shape + (16,), np.uint8), ws.array("texture", gl.shape,
                                                                       np.int32)):
        arr.fill(77)
    reused = descriptor.compute_descriptors(gl, workspace=ws)
    assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(fresh, reused))

    pts = np.array([[20, 20, 10], [60, 30, 14], [100, 90, 30], [30, 80, 3]], np.int64)
    ws.array("grid_lists", (5, 6, 41), np.int32).fill(9)
    for right_image in (False, True):
        a = grid.disparity_grid(pts, (110, 95), 20, 0, 40, right_image=right_image)
        b = grid.disparity_grid(pts, (110, 95), 20, 0, 40, right_image=right_image,
                                workspace=ws)
        assert all(np.array_equal(x, y) for x, y in zip(a, b))

    disp = rng.integers(-1, 6, (50, 70)).astype(np.float32)
    disp[disp < 0] = -1.0
    for fn, args, kwargs in ((postprocess.remove_small_segments, (1.0, 5), {}),
                             (postprocess.interpolate_gaps, (3,), {"extrapolate": True}),
                             (postprocess.adaptive_mean, (), {}),
                             (postprocess.median_filter, (), {})):
        expect = fn(disp, *args, **kwargs)
        for _ in range(2):
            got = fn(disp, *args, workspace=ws, **kwargs)
            assert got.tobytes() == expect.tobytes(), fn.__name__
    checked, _ = postprocess.left_right_check(disp, disp[:, ::-1].copy(), 1.0, workspace=ws)
    assert np.array_equal(checked, postprocess.left_right_check(disp, disp[:, ::-1].copy(),
                                                                1.0)[0])


def test_concurrent_runs_in_two_threads_match_sequential_runs(pairs):
    import numba

    p = make_params("robotics", disp_min=0, disp_max=100)
    expect = [snapshot(elas_run(gl, gr, p, want_right=True)) for gl, gr in pairs]
    got: dict[int, list] = {0: [], 1: []}
    errors = []

    def work(k):
        try:
            numba.set_num_threads(1)
            for _ in range(3):
                got[k].append(snapshot(elas_run(*pairs[k], p, want_right=True)))
        except Exception as exc:   # surfaced below
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(k,)) for k in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    for k in (0, 1):
        assert len(got[k]) == 3 and all(same(r, expect[k]) for r in got[k])


def test_thread_budget_is_one_thread_at_640x480_and_every_core_at_hd():
    """The automatic budget (disparity_node's default ``threads: -1``): one thread for
    640x480-class frames, every core for 1280x720; 0 = every core; N capped at the limit."""
    from canopy_stereo.elas.parallel import AUTO_THREADS, budget_threads

    assert budget_threads(AUTO_THREADS, pixels=640 * 480, limit=2) == 1
    assert budget_threads(AUTO_THREADS, pixels=741 * 497, limit=2) == 1
    assert budget_threads(AUTO_THREADS, pixels=1280 * 720, limit=2) == 2
    assert budget_threads(0, pixels=640 * 480, limit=2) == 2
    assert budget_threads(3, pixels=1280 * 720, limit=2) == 2
    assert budget_threads(1, pixels=1280 * 720, limit=8) == 1
    assert budget_threads(AUTO_THREADS, pixels=1280 * 720, limit=0) == 1
