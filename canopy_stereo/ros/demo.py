"""The bundled-bag demo (``canopy-stereo demo``): bags through the graph -> PLYs, PNGs, summary.

For each bundled scene (:mod:`canopy_stereo.ros.bundled`) the bag is replayed
through the real nodes as ``canopy-stereo run`` does, and the first frame is written as:

* ``<scene>.ply``: the whole cloud, ``<scene>_plant.ply``: the plant only (the
  points on the plant mask), both millimetres in the rig's world frame, RGB (as every
  PLY of the package; the ROS messages themselves are metres, REP 103);
* ``<scene>_disparity.png`` and ``<scene>_depth.png``: colour-coded with a colour bar
  and units (pixels, metres), ``<scene>_mask.png`` (the plant mask measured, on the
  left image) and ``<scene>_overlay.png`` (its outline over the left image);
* ``<scene>_measurements.png``: top and side views of the plant with its measured
  canopy box and leaves (:func:`canopy_stereo.measure.plot_views`; needs matplotlib);
* ``<scene>_summary.txt``: frames, speed after warm-up, the canopy measurements
  (height, width, depth, hull and voxel volumes, leaf count) and, for scenes with a
  truth depth (the croton), the depth error.

The plant is measured by the package's one measuring pipeline
(:func:`canopy_stereo.measure.plant.measure_plant`) on the left image the graph received
and its disparity: the numbers are those of ``reconstruct --measure``, ``batch`` and ``view``
for the same pair (lengths mm, areas cm^2, volumes cm^3).
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
from canopy_stereo.ros.convert import cloud2_to_points, msg_to_bgr, msg_to_disparity
from canopy_stereo.ros.graph import GraphOptions
from canopy_stereo.ros.runner import run_bag
from canopy_stereo.viz.colour import depth_picture, disparity_picture


def disparity_png(frame, title: str = "disparity") -> np.ndarray:
    """BGR picture of a ``DisparityImage`` frame with a colour bar in pixels (the message's
    values, ``Z = f t / d``; the package's turbo map, near = red, invalid black)."""
    return disparity_picture(frame.disparity, title=title, unit="px")


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
    # the raw left image the graph received: the measuring pipeline finds the plant on it
    from sensor_msgs.msg import CompressedImage

    extra = {**(view.extra_outputs if view is not None else {}), "left/image_raw": Image,
             "left/image_raw/compressed": CompressedImage}
    result = run_bag(bag, rig, rate=0, options=GraphOptions(matcher=matcher, parameter_services=False),
                     domain_id=domain_id, keep=("points2", "disparity", "left/image_raw", "left/image_raw/compressed"),
                     extra_outputs=extra,
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
    left = _raw_left(result, stamp)
    if stamp in disps and left is not None:
        lines += ["  " + s for s in _measure(scene, frame, left, rig, out_dir, files, stamp)]
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


def _raw_left(result, stamp: int):
    """The raw left image (BGR) the graph received for ``stamp`` (raw or ``/compressed``), or None."""
    from canopy_stereo.ros.compressed import decompress_image_cdr

    raw = dict(result.outputs.get("left/image_raw", []))
    packed = dict(result.outputs.get("left/image_raw/compressed", []))
    data = raw.get(stamp)
    if data is None and stamp in packed:
        data = decompress_image_cdr(packed[stamp])
    return None if data is None else msg_to_bgr(deserialize_message(data, Image))


def _measure(scene: str, frame, left, rig, out_dir: Path, files: list, stamp: int) -> list[str]:
    """Measure the plant of the graph's frame with the package's one measuring pipeline
    (:func:`~canopy_stereo.measure.plant.measure_plant` on the raw left image and the
    graph's disparity, as ``reconstruct --measure``, ``batch`` and ``view``); write the mask,
    its overlay, the plant PLY and the plot; summary lines."""
    from canopy_stereo.measure import plot_views
    from canopy_stereo.measure.plant import measurement_lines, write_overlay
    from canopy_stereo.ros.measuring import measure_graph_frame

    try:
        measured = measure_graph_frame(left, frame, rig)
    except CanopyStereoError as exc:
        return [f"canopy: not measured ({exc})"]
    mask = measured.mask
    files.append(write_image(out_dir / f"{scene}_mask.png", mask.astype(np.uint8) * 255))
    files.append(write_overlay(out_dir / f"{scene}_overlay.png", measured, left))
    lines = [f"plant mask: {mask.mean() * 100:.1f} % of the left image"]
    org = measured.organized_mm
    plant = mask & np.all(np.isfinite(org), axis=-1)
    files.append(write_ply(out_dir / f"{scene}_plant.ply", org[plant], colors=left[..., ::-1][plant], unit="mm",
                           comments=[f"canopy-stereo demo scene={scene} frame_stamp_ns={stamp} (plant mask only)"]))
    lines.append(f"plant cloud: {int(plant.sum())} points")
    lines += measurement_lines(measured.report)
    try:
        files.append(plot_views(measured.scene, out_dir / f"{scene}_measurements.png",
                                title=f"{scene}: plant measured from the first frame (mm)"))
    except CanopyStereoError as exc:
        lines.append(f"measurement plot skipped: {exc}")
    return lines
