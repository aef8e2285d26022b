"""The bundled-bag demo (``canopy-stereo demo``): bags through the graph -> PLY, PNGs, summary.

For each bundled scene (:mod:`canopy_stereo.ros.bundled`) the bag is replayed
through the real nodes as ``canopy-stereo run`` does, and the first frame's
cloud is written as ``<out>/<scene>.ply`` (metres, RGB), with
``<scene>_disparity.png`` (colour-coded, invalid black), ``<scene>_mask.png``
(GrabCut) and ``<scene>_summary.txt``. Scenes with a truth depth (the croton)
also report the depth error.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image, PointCloud2
from stereo_msgs.msg import DisparityImage

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import write_image
from canopy_stereo.io.ply import write_ply
from canopy_stereo.io.rig import load_rig
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig, read_truth_depths, relative_depth_errors
from canopy_stereo.ros.convert import cloud2_to_points, msg_to_disparity, msg_to_image
from canopy_stereo.ros.graph import GraphOptions
from canopy_stereo.ros.runner import run_bag


def disparity_png(frame) -> np.ndarray:
    """BGR colour image of a disparity (turbo colour map over its valid range, invalid black)."""
    d = frame.disparity
    valid = np.isfinite(d)
    out = np.zeros(d.shape + (3,), np.uint8)
    if valid.any():
        lo, hi = np.percentile(d[valid], [1, 99])
        scaled = np.clip((d - lo) / max(hi - lo, 1e-6) * 255, 0, 255)
        scaled = np.where(valid, scaled, 0).astype(np.uint8)
        cmap = getattr(cv2, "COLORMAP_TURBO", cv2.COLORMAP_JET)
        out = cv2.applyColorMap(scaled, cmap)
        out[~valid] = 0
    return out


def run_scene(scene: str, out_dir, matcher=None, domain_id=None, view=None) -> list[str]:
    """Run one bundled scene; write its files and return the summary lines.

    ``view``: an optional :class:`~canopy_stereo.viz.sources.LiveView` the graph's outputs
    are streamed to as they arrive."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bag, rig_path = bundled_bag(scene), bundled_rig(scene)
    rig = load_rig(rig_path)
    result = run_bag(bag, rig, rate=0, options=GraphOptions(matcher=matcher, parameter_services=False),
                     domain_id=domain_id, keep=("points2", "disparity", "left/mask"),
                     extra_outputs=view.extra_outputs if view is not None else None,
                     on_output=view.on_output if view is not None else None)
    lines = [f"scene {scene}: {bag.name} through {rig_path.name}"] + ["  " + s for s in result.summary_lines()]
    clouds = sorted(result.outputs["points2"])
    if not clouds:
        raise CanopyStereoError(f"{scene}: the graph produced no point cloud")
    stamp, data = clouds[0]
    points, colors = cloud2_to_points(deserialize_message(data, PointCloud2))
    ply = write_ply(out_dir / f"{scene}.ply", points, colors, unit="m",
                    comments=[f"canopy-stereo demo scene={scene} frame_stamp_ns={stamp}"])
    files = [ply]
    disps = dict(result.outputs["disparity"])
    if stamp in disps:
        frame = msg_to_disparity(deserialize_message(disps[stamp], DisparityImage))
        files.append(write_image(out_dir / f"{scene}_disparity.png", disparity_png(frame)))
        valid = np.isfinite(frame.disparity)
        lines.append(f"  disparity: {valid.mean() * 100:.1f} % valid, f {frame.f:.1f} px, "
                     f"t {frame.t * 1e3:.2f} mm")
    masks = dict(result.outputs["left/mask"])
    if stamp in masks:
        mask = msg_to_image(deserialize_message(masks[stamp], Image))
        files.append(write_image(out_dir / f"{scene}_mask.png", mask))
        lines.append(f"  plant mask: {(mask > 0).mean() * 100:.1f} % of the rectified left image")
    lo, hi = points.min(axis=0), points.max(axis=0)
    lines.append(f"  first frame: {len(points)} points; box (m) x {lo[0]:.3f}..{hi[0]:.3f} "
                 f"y {lo[1]:.3f}..{hi[1]:.3f} z {lo[2]:.3f}..{hi[2]:.3f}")
    truth = read_truth_depths(bag)
    if truth:
        errors = []
        for s, d in clouds:
            if s in truth:
                pts, _ = cloud2_to_points(deserialize_message(d, PointCloud2))
                errors.append(np.median(relative_depth_errors(pts, rig, truth[s])))
        if errors:
            lines.append(f"  depth error vs truth: median {np.median(errors) * 100:.2f} % "
                         f"(per frame {', '.join(f'{e * 100:.2f}' for e in errors)} %)")
    lines.append("  wrote " + ", ".join(str(f) for f in files))
    summary = out_dir / f"{scene}_summary.txt"
    summary.write_text("\n".join(lines) + "\n", encoding="utf-8")
    lines.append(f"  summary: {summary}")
    return lines
