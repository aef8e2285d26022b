"""The bundled-bag demo (``canopy-stereo demo``): bags through the graph -> PLYs, PNGs, summary.

For each bundled scene (:mod:`canopy_stereo.ros.bundled`) the bag is replayed
through the real nodes as ``canopy-stereo run`` does, and the first frame is written as:

* ``<scene>.ply``: the whole cloud, ``<scene>_plant.ply``: the plant only (the
  points on the GrabCut mask), both millimetres in the rig's world frame, RGB (as every
  PLY of the package; the ROS messages themselves are metres, REP 103);
* ``<scene>_disparity.png`` and ``<scene>_depth.png``: colour-coded with a colour bar
  and units (pixels, metres), ``<scene>_mask.png`` (GrabCut);
* ``<scene>_measurements.png``: top and side views of the plant with its measured
  canopy box and leaves (:func:`canopy_stereo.measure.plot_views`; needs matplotlib);
* ``<scene>_summary.txt``: frames, speed after warm-up, the canopy measurements
  (height, width, depth, hull and voxel volumes, leaf count) and, for scenes with a
  truth depth (the croton), the depth error.
"""
from __future__ import annotations

from pathlib import Path

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
from canopy_stereo.viz.colour import depth_picture, disparity_picture


def disparity_png(frame, title: str = "disparity") -> np.ndarray:
    """BGR picture of a ``DisparityImage`` frame with a colour bar in pixels (the message's
    values, ``Z = f t / d``; the package's turbo map, near = red, invalid black)."""
    return disparity_picture(frame.disparity, title=title, unit="px")


def organize_on_rectified_grid(points_m: np.ndarray, colors, rig, size) -> tuple[np.ndarray, np.ndarray]:
    """Put a dense cloud (N, 3) metres back on the rectified left pixel grid it came from.

    Every point of ``point_cloud_node`` lies on the ray of its rectified left pixel
    (the rectified and the original left camera share their centre), so projecting
    it through the rectified left camera finds that pixel. Returns ``(organized (H, W, 3)
    millimetres, NaN = none; colours (H, W, 3) uint8)`` with ``size = (W, H)``.
    """
    from canopy_stereo.geometry.camera import project
    from canopy_stereo.geometry.clouds import check_cloud
    from canopy_stereo.geometry.rectification import fusiello_rectify

    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    w, h = int(size[0]), int(size[1])
    organized = np.full((h, w, 3), np.nan)
    cols = np.zeros((h, w, 3), np.uint8)
    pts = check_cloud(points_m, organized=None, name="points").reshape(-1, 3)
    ok = np.all(np.isfinite(pts), axis=1)
    uv = np.rint(project(rect.P_rect_left, pts[ok] / rig.metres_per_unit)).astype(np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    organized[uv[inside, 1], uv[inside, 0]] = pts[ok][inside] * 1000.0
    if colors is not None:
        cols[uv[inside, 1], uv[inside, 0]] = np.asarray(colors).reshape(-1, 3)[ok][inside]
    return organized, cols


def steady_speed_lines(result) -> list[str]:
    """Speed after warm-up: the first frame is left out (it pays for compiling or loading
    the numba kernels and for the graph's first allocations)."""
    times, lat = result.completed_at_s, np.asarray(result.latencies_s) * 1e3
    if len(times) >= 3:
        fps = (len(times) - 1) / max(times[-1] - times[0], 1e-9)
        return [f"speed after warm-up (first frame left out): {fps:.2f} frames/s, latency median "
                f"{np.median(lat[1:]):.0f} ms; with warm-up {result.fps:.2f} frames/s, first frame "
                f"{lat[0]:.0f} ms (figures of a busy machine are noisy: benchmarks/bench_graph.py)"]
    return [f"speed: {len(times)} frame(s) only, no figure after warm-up (the first frame includes "
            f"it: {lat[0]:.0f} ms; benchmarks/bench_graph.py measures the speed)" if len(lat) else
            "speed: no frame came out"]


def canopy_lines(report: dict) -> list[str]:
    """Summary lines of a measurement REPORT dict in millimetres."""
    c = report["canopy"]
    lines = [f"canopy (plant mask): height {c['height']:.0f} mm, width {c['width']:.0f} mm, "
             f"depth {c['depth']:.0f} mm"
             + (f", top {c['top_above_ground']:.0f} mm above the ground" if c.get("top_above_ground") else ""),
             f"  volumes: convex hull {c['hull_volume'] / 1e6:.2f} L, voxels {c['voxel_volume'] / 1e6:.2f} L "
             f"({c['voxel_size']:.0f} mm voxels); leaves measured: {c.get('n_leaves', 0)}"
             + (f", leaf area {c['leaf_area'] / 100:.0f} cm^2" if c.get("leaf_area") else "")]
    for leaf in report.get("leaves", [])[:8]:
        lines.append(f"  leaf {leaf['id']}: length {leaf['length']:.0f} mm, width {leaf['width']:.0f} mm, "
                     f"area {leaf['area'] / 100:.1f} cm^2")
    if len(report.get("leaves", [])) > 8:
        lines.append(f"  ... {len(report['leaves']) - 8} more leaves")
    return lines


def run_scene(scene: str, out_dir, *, matcher=None, domain_id=None, view=None,
              compressed: bool = False) -> list[str]:
    """Run one bundled scene; write its files and return the summary lines.

    ``view``: an optional :class:`~canopy_stereo.ros.viewer.LiveView` the graph's outputs
    are streamed to as they arrive. ``compressed``: replay the bag with its images as JPEG
    (quality 95) ``CompressedImage``, as a robot records them (written to
    ``out_dir/<scene>_compressed.mcap`` by :func:`~canopy_stereo.ros.bag_images.compress_bag`)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    bag, rig_path = bundled_bag(scene), bundled_rig(scene)
    if compressed:
        from canopy_stereo.ros.bag_images import compress_bag

        packed = out_dir / f"{scene}_compressed.mcap"
        compress_bag(bag, packed, overwrite=True)
        bag = packed
    rig = load_rig(rig_path)
    result = run_bag(bag, rig, rate=0, options=GraphOptions(matcher=matcher, parameter_services=False),
                     domain_id=domain_id, keep=("points2", "disparity", "left/mask"),
                     extra_outputs=view.extra_outputs if view is not None else None,
                     on_output=view.on_output if view is not None else None)
    lines = [f"scene {scene}: {bag.name} through {rig_path.name}"]
    lines += ["  " + s for s in result.summary_lines() if not s.startswith(("throughput", "latency"))]
    lines += ["  " + s for s in steady_speed_lines(result)]
    clouds = sorted(result.outputs["points2"])
    if not clouds:
        raise CanopyStereoError(f"{scene}: the graph produced no point cloud")
    stamp, data = clouds[0]
    points, colors = cloud2_to_points(deserialize_message(data, PointCloud2))
    ply = write_ply(out_dir / f"{scene}.ply", points * 1000.0, colors=colors, unit="mm",
                    comments=[f"canopy-stereo demo scene={scene} frame_stamp_ns={stamp} (whole scene)"])
    files = [ply]
    disps = dict(result.outputs["disparity"])
    if stamp in disps:
        frame = msg_to_disparity(deserialize_message(disps[stamp], DisparityImage))
        files.append(write_image(out_dir / f"{scene}_disparity.png",
                                 disparity_png(frame, title=f"{scene}: disparity")))
        files.append(write_image(out_dir / f"{scene}_depth.png",
                                 depth_picture(frame.depth(), title=f"{scene}: depth along the optical axis",
                                               unit="m")))
        valid = np.isfinite(frame.disparity)
        lines.append(f"  disparity: {valid.mean() * 100:.1f} % valid, f {frame.f:.1f} px, "
                     f"t {frame.t * 1e3:.2f} mm")
    masks = dict(result.outputs["left/mask"])
    if stamp in masks:
        mask = msg_to_image(deserialize_message(masks[stamp], Image))
        files.append(write_image(out_dir / f"{scene}_mask.png", mask))
        lines.append(f"  plant mask: {(mask > 0).mean() * 100:.1f} % of the rectified left image")
        organized, org_colors = organize_on_rectified_grid(points, colors, rig, mask.shape[::-1])
        plant = (mask > 0) & np.all(np.isfinite(organized), axis=-1)
        files.append(write_ply(out_dir / f"{scene}_plant.ply", organized[plant], colors=org_colors[plant],
                               unit="mm",
                               comments=[f"canopy-stereo demo scene={scene} frame_stamp_ns={stamp} "
                                         "(plant mask only)"]))
        lines.append(f"  plant cloud: {int(plant.sum())} of {len(points)} points")
        lines += ["  " + s for s in _measure(scene, organized, mask, rig, out_dir, files)]
    lo, hi = points.min(axis=0) * 1000.0, points.max(axis=0) * 1000.0
    lines.append(f"  first frame: {len(points)} points; box (mm) x {lo[0]:.0f}..{hi[0]:.0f} "
                 f"y {lo[1]:.0f}..{hi[1]:.0f} z {lo[2]:.0f}..{hi[2]:.0f}")
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


def _measure(scene: str, organized_mm: np.ndarray, mask: np.ndarray, rig, out_dir: Path, files: list) -> list[str]:
    """Measure the plant (leaves and canopy, millimetres) and plot it; summary lines."""
    from canopy_stereo.geometry.rectification import fusiello_rectify
    from canopy_stereo.measure import measure_scene, plot_views

    rect = fusiello_rectify(rig.P_left, rig.P_right, rig.image_size)
    k = 1e-3 / rig.metres_per_unit  # millimetres -> world units
    P_mm = rect.P_rect_left @ np.diag([k, k, k, 1.0])
    try:
        measured = measure_scene(organized_mm, mask=mask > 0, unit="mm", camera=P_mm)
    except CanopyStereoError as exc:
        return [f"canopy: not measured ({exc})"]
    lines = canopy_lines(measured.report)
    try:
        files.append(plot_views(measured, out_dir / f"{scene}_measurements.png",
                                title=f"{scene}: plant measured from the first frame (mm)"))
    except CanopyStereoError as exc:
        lines.append(f"measurement plot skipped: {exc}")
    return lines
