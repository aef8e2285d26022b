"""Foundation benchmark: triangulation throughput and reconstruct stage times.

Prints:
* DLT triangulation of 300k exact correspondences through the paper rig (median of 7 calls
  after a warm-up), with the worst relative error;
* ``reconstruct_pair`` stage times on the bundled Plants pair (median of 3 calls).

Run: ``.venv/bin/python benchmarks/bench_triangulation.py``
"""
from __future__ import annotations

import statistics
import time
from pathlib import Path

import numpy as np

from canopy_stereo.geometry.camera import project
from canopy_stereo.geometry.triangulation import triangulate_dlt
from canopy_stereo.io.images import read_image
from canopy_stereo.io.rig import load_rig
from canopy_stereo.pipeline.reconstruct import reconstruct_pair

ROOT = Path(__file__).resolve().parents[1]


def bench_triangulation(n: int = 300_000) -> None:
    rig = load_rig(ROOT / "config/paper_rig.yaml")
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(-200, 250, n), rng.uniform(-200, 100, n), rng.uniform(400, 900, n)])
    xl, xr = project(rig.P_left, X), project(rig.P_right, X)
    triangulate_dlt(rig.P_left, rig.P_right, xl[:10], xr[:10])
    times = []
    for _ in range(7):
        t = time.perf_counter()
        Xe = triangulate_dlt(rig.P_left, rig.P_right, xl, xr)
        times.append(time.perf_counter() - t)
    rel = np.nanmax(np.linalg.norm(Xe - X, axis=1) / np.linalg.norm(X, axis=1))
    print(f"triangulate_dlt {n} points: median {statistics.median(times) * 1e3:.1f} ms, "
          f"min {min(times) * 1e3:.1f} ms, max relative error {rel:.1e}")


def bench_reconstruct(matcher: str = "sgbm") -> None:
    rig = load_rig(ROOT / "config/plants_rig.yaml")
    left = read_image(ROOT / "examples/plants/left.png")
    right = read_image(ROOT / "examples/plants/right.png")
    reconstruct_pair(left, right, rig, matcher=matcher)
    runs = [reconstruct_pair(left, right, rig, matcher=matcher).timings for _ in range(3)]
    stages = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    total = sum(stages.values())
    print(f"reconstruct_pair Plants 710x496 ({matcher}): " +
          ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in stages.items()) + f"; total {total * 1e3:.0f} ms")


if __name__ == "__main__":
    bench_triangulation()
    bench_reconstruct("sgbm")
    try:
        bench_reconstruct("elas")
    except Exception as exc:  # noqa: BLE001 - report and go on
        print(f"reconstruct_pair with elas: unavailable ({exc})")
