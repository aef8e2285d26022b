"""Benchmark: disparity only in the plant region of the previous masks (issue 28 item 1).

For a sequence of frames, ``disparity_node``'s matching with ``roi`` (the window of
:class:`canopy_stereo.disparity.roi.RoiPlanner` fed the previous frame's plant mask) against
the full frame: CPU ms per frame of each (``time.process_time``, the matcher on one thread, as
in the 4-process graph on 2 cores: ``--threads``), the share of the frame matched, how many
frames fell back to the full frame and why, and the agreement on the plant pixels (density
of each path, disparities identical / within 1 px).

Scenes: ``plants`` (bench_graph's frames: the real Middlebury Plants pair, a crop drifting a few
pixels per frame with fresh noise, rectified as rectify_node does with the rig of the size; masks
from segment_node's propagated GrabCut) and ``pots`` (the simulator's two potted plants side by
side seen from a rig moving along its baseline; masks = the true leaves). Sizes ``WxH``.

    .venv/bin/python benchmarks/bench_roi.py --scene plants --size 640x480 1280x720 --frames 20
    .venv/bin/python benchmarks/bench_roi.py --scene pots --size 640x480 --frames 10
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def plants_frames(size: tuple[int, int], n: int):
    """``(rig, [(left, right, None)])``: bench_graph's Plants frames (raw) of ``size``: one of
    bench_graph's sizes, or 1280x720 (the 1280x960 frames' middle 720 rows)."""
    import bench_graph

    if size == (1280, 720):
        rig, frames = bench_graph.bench_frames("plants", "1280x960", n)
        rig = bench_graph.scaled_rig(rig, 1.0, (0, 120), (1280, 720))
        return rig, [(left[120:840], right[120:840], None) for left, right in frames]
    rig, frames = bench_graph.bench_frames("plants", f"{size[0]}x{size[1]}", n)
    return rig, [(left, right, None) for left, right in frames]


def pots_frames(size: tuple[int, int], n: int):
    """``(rig, [(left, right, true leaf mask)])``: the simulator's pots seen from a moving rig."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.sim import rig_at_resolution
    from canopy_stereo.sim.sequence import CaptureTiming, RigMotion, SequenceSpec, render_sequence

    rig = load_rig(Path(__file__).resolve().parents[1] / "config" / "paper_rig.yaml")
    rig = rig_at_resolution(rig, size[0] / rig.image_size[0])
    spec = SequenceSpec(scene="pots_side_by_side", frames=n, supersample=1, motion=RigMotion("along", 0.12),
                        timing=CaptureTiming(fps=15.0))
    return rig, [(f.left, f.right, (f.leaf_ids_left > 0).astype(np.uint8) * 255)
                 for f in render_sequence(spec, rig)]


def run(scene: str, size: tuple[int, int], n: int, threads: int) -> None:
    from canopy_stereo.disparity import compute_disparity
    from canopy_stereo.disparity.roi import RoiPlanner, disparity_in_window
    from canopy_stereo.geometry.rectification import cached_rectifier
    from canopy_stereo.io.images import to_gray
    from canopy_stereo.pipeline.reconstruct import disparity_range_for, rectify_rig
    from canopy_stereo.ros.nodes.disparity import apply_thread_budget
    from canopy_stereo.segmentation.auto import VIDEO_SEEDER
    from canopy_stereo.segmentation.propagate import MaskPropagator

    rig, frames = (plants_frames if scene == "plants" else pots_frames)(size, n)
    rect = rectify_rig(rig, "fusiello")
    rectifier = cached_rectifier(rig, rect)
    dmin, dmax = disparity_range_for(rig, rect)
    apply_thread_budget(threads)
    segmenter = MaskPropagator(settings=VIDEO_SEEDER)
    planner = RoiPlanner()
    cpu = {"full": 0.0, "roi": 0.0}
    shares, reasons, agree = [], Counter(), []
    for k, (left, right, truth) in enumerate(frames):
        lc, rc = rectifier.rectify(left, right)
        gl, gr = to_gray(lc), to_gray(rc)
        mask = (segmenter.segment(lc) if truth is None else rectifier.rectify_one(truth, "left"))
        if k == 0:  # first-call costs out of the figures
            compute_disparity(gl, gr, disp_min=dmin, disp_max=dmax)
        window, reason = planner.plan(k, image_size=gl.shape[::-1], disp_min=dmin, disp_max=dmax)
        t = time.process_time()
        full = compute_disparity(gl, gr, disp_min=dmin, disp_max=dmax)
        cpu["full"] += time.process_time() - t
        t = time.process_time()
        roi = (compute_disparity(gl, gr, disp_min=dmin, disp_max=dmax) if window is None else
               disparity_in_window(gl, gr, window, matcher="elas", disp_min=dmin, disp_max=dmax))
        cpu["roi"] += time.process_time() - t
        shares.append(1.0 if window is None else window.matched_share)
        if window is None:
            reasons[reason] += 1
        plant = mask >= 128
        if window is not None and plant.any():
            vf, vr = plant & (full >= 0), plant & (roi >= 0)
            both = vf & vr
            diff = np.abs(full[both] - roi[both])
            agree.append((vf.mean() / plant.mean(), vr.mean() / plant.mean(), np.mean(diff == 0),
                          np.mean(diff <= 1)))
        planner.observe(k, mask)
    a = np.array(agree) if agree else np.full((1, 4), np.nan)
    print(f"{scene} {size[0]}x{size[1]} ({n} frames, disparities {dmin}..{dmax}, {threads} thread(s)): "
          f"CPU ms per frame full {cpu['full'] / n * 1e3:.1f}, roi {cpu['roi'] / n * 1e3:.1f} "
          f"({cpu['roi'] / cpu['full']:.2f}x); matched share mean {np.mean(shares):.2f}; "
          f"full frames {dict(reasons)}")
    print(f"    plant pixels (windowed frames): density full {np.mean(a[:, 0]):.4f} roi {np.mean(a[:, 1]):.4f}; "
          f"disparity identical {np.mean(a[:, 2]):.4f}, within 1 px {np.min(a[:, 3]):.4f} (worst frame)", flush=True)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scene", choices=("plants", "pots"), default="plants")
    p.add_argument("--size", nargs="+", default=["640x480"], help="frame sizes WxH")
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--threads", type=int, default=1, help="ELAS threads (default 1: the graph's share)")
    args = p.parse_args(argv)
    for size in args.size:
        w, h = (int(v) for v in size.lower().split("x"))
        run(args.scene, (w, h), args.frames, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
