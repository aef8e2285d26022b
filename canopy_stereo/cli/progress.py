"""No silent waits: the first-run compile notice and progress on a terminal.

* :func:`warm_up_kernels` runs the numba kernels of ELAS and triangulation once on a
  tiny synthetic pair. On the first run of an installation numba compiles them (about
  15 s to a minute; cached on disk afterwards): if that takes longer than a second the
  user is told what is happening, and when it is done, how long it took.
* progress of a long command: the package's one reporter,
  :class:`canopy_stereo.progress.Progress` (``label k/N`` with the elapsed time and an
  estimate of the rest on a terminal; quiet in logs and CI).

It writes to stderr, so stdout keeps only a command's results.
"""
from __future__ import annotations

import sys
import threading
import time

import numpy as np

_WARMED = False


def _exercise() -> None:
    """Run the kernels a live graph and ``reconstruct`` use, on a small textured pair
    (a plane 8 pixels of disparity away, so that every ELAS stage has work)."""
    import warnings

    import cv2

    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.geometry.rectification import fusiello_rectify
    from canopy_stereo.geometry.triangulation import triangulate_disparity, triangulate_disparity_points

    rng = np.random.default_rng(0)
    w, h, shift = 160, 120, 8
    coarse = rng.random((h // 4, (w + shift) // 4)).astype(np.float32)
    texture = cv2.resize(coarse, (w + shift, h), interpolation=cv2.INTER_CUBIC)
    texture = np.clip((texture - texture.min()) / np.ptp(texture) * 255, 0, 255).astype(np.uint8)
    left, right = np.ascontiguousarray(texture[:, :w]), np.ascontiguousarray(texture[:, shift:])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for subpixel in (False, True):
            disp = compute_disparity(left, right, matcher="elas", disp_min=0, disp_max=24, subpixel=subpixel)
    K = np.array([[100.0, 0, w / 2], [0, 100.0, h / 2], [0, 0, 1]])
    P_left = K @ np.hstack([np.eye(3), np.zeros((3, 1))])
    P_right = K @ np.hstack([np.eye(3), [[-60.0], [0], [0]]])
    rect = fusiello_rectify(P_left, P_right, (w, h))
    mask = np.ones((h, w), np.uint8)
    for organized in (False, True):
        for m in (None, mask):
            triangulate_disparity_points(disp, rect, P_left, P_right, scale=0.001, mask=m, organized=organized)
    triangulate_disparity(disp, rect, P_left, P_right)  # the organized grid of reconstruct


def _cache_misses() -> int:
    """Kernels numba compiled (rather than loaded from its cache) in this process so far."""
    from numba.core.registry import CPUDispatcher

    misses = 0
    for name, mod in list(sys.modules.items()):
        if not name.startswith("canopy_stereo") or mod is None:
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, CPUDispatcher) and obj.__module__ == name:
                misses += sum(obj.stats.cache_misses.values())
    return misses


def warm_up_kernels(*, say_after_s: float = 2.0, stream=None) -> float | None:
    """Load, or on the first run compile, the numba kernels before the real work starts.

    Says so on ``stream`` (stderr) when it takes longer than ``say_after_s``, and then
    how long it took. Once per process; returns the seconds spent (None if already warm).
    """
    global _WARMED
    if _WARMED:
        return None
    stream = stream or sys.stderr
    done = threading.Event()
    errors: list[BaseException] = []

    def work():
        try:
            _exercise()
        except BaseException as exc:  # noqa: BLE001 - reported below; the real work will fail clearly
            errors.append(exc)
        finally:
            done.set()

    t0 = time.perf_counter()
    threading.Thread(target=work, name="numba_warm_up", daemon=True).start()
    said = False
    if not done.wait(say_after_s):
        print("preparing the numba kernels (ELAS disparity, triangulation): compiled for this machine "
              "on the first run only (15-60 s), loaded from the disk cache afterwards ...",
              file=stream, flush=True)
        said = True
        done.wait()
    elapsed = time.perf_counter() - t0
    _WARMED = not errors
    compiled = _cache_misses() if not errors else 0
    if said or compiled:
        what = f"compiled {compiled} kernels" if compiled else "loaded the kernels"
        print(f"{what} in {elapsed:.1f} s" + (" (cached for later runs)" if compiled else ""),
              file=stream, flush=True)
    return elapsed
