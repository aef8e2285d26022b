"""Benchmark: the ROS 2 node graph at camera rate (issues 5, 12, 15).

Per configuration (``--configs``; ``--quick`` for the two headline ones, ``--hd`` for the four
1280x720 ones, no option for all 32), the graph is fed by two camera publishers at ``--rate`` (30) frames/s with
bgr8 pairs of **real plant images** (Middlebury 2014 "Plants", the pair in the bundled
``bags/plants.mcap``, cropped to 640x480 and resized to the configuration's size; the
crop window drifts by a few pixels and sensor noise changes every frame, as a hand-held
rig's would; ``--scene croton`` uses the bundled synthetic croton instead, ``--scene aloe`` the
held-out Middlebury 2006 Aloe with disparities to about 130 px, from ``../shared/data``:
``test/support/aloe.py``), and prints:

* clouds/s offered (pairs published per second) and delivered (``points2`` received for
  them per second, first pair published -> last cloud received) and their ratio;
* latency median and 95th percentile: a pair's stamp (the wall clock when the left image
  is published, as a camera driver stamps it) to its cloud's arrival in the feeding process;
* CPU ms per node per offered pair (and per frame the node output, ``/out``): user + system time from
  ``/proc/<pid>/stat`` of each node
  process (its DDS threads included) or, in one process, from ``/proc/self/task/<tid>/stat``
  of each node's threads (executor, worker, ELAS pool; DDS threads count as ``dds``); the
  feeding process (publishers + the cloud subscriber) is ``feed``;
* frames each node output (``out`` totals on ``/diagnostics``) and inputs it dropped;
* memory: peak RSS (``VmHWM``) of each node process, or of the one process.

Configuration ``MODE:MATCHER:MASK:SIZE[:TRANSPORT]``: MODE ``processes`` (rectify, disparity,
[segment,] point_cloud, one process each, as ``ros2 run``/the launch file start them) or
``inprocess`` (the same nodes in one process, as ``canopy_graph``/``canopy-stereo run``);
MATCHER ``elas``/``sgbm``; MASK ``mask`` (segment_node runs and point_cloud_node keeps only
plant pixels, ``use_mask``) or ``nomask`` (no segment_node); SIZE ``320x240``, ``640x480``,
``1280x720`` (the middle 640x360 of the 640x480 window, scaled twice: an HD webcam mode) or
``1280x960``; TRANSPORT ``raw`` (default: bgr8 ``Image`` on ``<side>/image_raw``) or
``compressed`` (the cameras send JPEG, quality ``--jpeg-quality`` 95, as ``CompressedImage`` on
``<side>/image_raw/compressed``, encoded beforehand as a webcam's MJPEG is; rectify_node runs
with ``image_transport: compressed`` and decodes each frame; ``--compressed`` = the two
``--quick`` configurations with compressed inputs). Each configuration runs in a fresh
process (``--one``), so that memory peaks and numba/DDS state do not carry over. CPU time is
much less sensitive to a loaded machine than wall-clock rates: the targets (>= 27 clouds/s,
median latency < 100 ms, 640x480 at 30 Hz, on 2 cores) need the nodes' CPU per pair to stay
below 2 cores x 33 ms = 66 ms in total.

    .venv/bin/python benchmarks/bench_graph.py --quick
    .venv/bin/python benchmarks/bench_graph.py --compressed   # JPEG camera streams
    .venv/bin/python benchmarks/bench_graph.py --configs processes:elas:mask:640x480 --frames 150
    .venv/bin/python benchmarks/bench_graph.py --hd --frames 60   # 1280x720, raw and JPEG, masked or not
    .venv/bin/python benchmarks/bench_graph.py            # all 32 configurations (~20 min)

``--foreign-driver`` (issue 29): the node processes (rectify, ELAS, point_cloud) fed by a driver that
is not ours (``test/support/foreign_driver.py``, Fast DDS's defaults, no package profile) at
``--rate``, with the package's 4 MiB UDP receive buffer and with the 208 kB a stock kernel's
``net.core.rmem_max`` caps it to: clouds per pair, clouds/s, latency median and p95.

    .venv/bin/python benchmarks/bench_graph.py --foreign-driver --rate 30 --frames 300

Older modes, kept: ``--replay`` replays a croton bag through the in-process graph as fast as
possible (``--matchers``, ``--executors``, ``--no-cli``: frames/s, latency, busy time per node);
``--processes`` / ``--processes-only`` compare the four node processes with the in-process
graph fed the croton frames at ``--rates`` (issue 12's benchmark).
"""
from __future__ import annotations

import argparse
import collections
import contextlib
import io
import os
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.cli import main as cli_main  # noqa: E402
from canopy_stereo.io.rig import load_rig  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig, write_stereo_bag  # noqa: E402
from canopy_stereo.ros.convert import msg_to_image  # noqa: E402
from canopy_stereo.ros.graph import GraphOptions  # noqa: E402
from canopy_stereo.ros.runner import run_bag  # noqa: E402


def make_bag(path: Path, n_frames: int, fps: float = 15.0) -> Path:
    """``n_frames`` croton frames (the bundled ones, cycled) with fresh stamps."""
    bag = BagReader(bundled_bag("croton"))
    lefts = [msg_to_image(m).copy() for _, m in bag.read("/stereo/left/image_raw")]
    rights = [msg_to_image(m).copy() for _, m in bag.read("/stereo/right/image_raw")]
    t0, period = 1_704_067_200_000_000_000, int(1e9 / fps)
    frames = [(lefts[k % len(lefts)], rights[k % len(rights)], t0 + k * period, t0 + k * period + 4_000_000)
              for k in range(n_frames)]
    return write_stereo_bag(path, frames, compression="lz4")


def bench_processes(rate_hz: float, n_frames: int, log_dir: Path, matcher: str = "elas",
                    segment: bool = True, domain_id: int | None = None) -> dict:
    """Four node processes fed at ``rate_hz``: clouds per offered pair and latency (s)."""
    import time

    import numpy as np
    from sensor_msgs.msg import Image, PointCloud2

    from canopy_stereo.ros.context import private_domain_id

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's test package
    from test.support.ros_harness import PROCESSING_NODES, Probe, ProcessGroup, croton_frames, feed_pairs, wait_for

    domain = private_domain_id() if domain_id is None else domain_id
    group = ProcessGroup(domain, log_dir)
    nodes = PROCESSING_NODES if segment else tuple(n for n in PROCESSING_NODES if n != "segment_node")
    probe = None
    try:
        group.start_graph(bundled_rig("croton"), nodes=nodes, params={"disparity_node": {"matcher": matcher}})
        probe = Probe(domain)
        pub_l, pub_r = probe.publisher(Image, "left/image_raw"), probe.publisher(Image, "right/image_raw")
        clouds = probe.subscribe(PointCloud2, "points2")
        frames = croton_frames()
        if not wait_for(lambda: clouds.subscription.get_publisher_count() >= 1
                        and pub_l.get_subscription_count() >= 1 and pub_r.get_subscription_count() >= 1,
                        60.0, group=group):
            raise RuntimeError("the node processes did not connect:\n" + group.logs())
        stamp = 1_600_000_000_000_000_000
        while len(clouds) == 0:  # warm-up: first-call costs
            feed_pairs(pub_l, pub_r, frames, [stamp], 1.0)
            stamp += 10**8
            wait_for(lambda: len(clouds) > 0, 2.0, group=group)
        time.sleep(1.0)
        t0 = 1_700_000_000_000_000_000
        stamps = [t0 + int(k * 1e9 / rate_hz) for k in range(n_frames)]
        sent = feed_pairs(pub_l, pub_r, frames, stamps, rate_hz)
        wait_for(lambda: set(stamps) <= set(clouds.stamps()), 3.0)
        with clouds.lock:
            arrivals = {s: t for t, s, _ in clouds.items if s in sent}
        lat = np.array([arrivals[s] - sent[s] for s in arrivals])
        return {"clouds_per_pair": len(arrivals) / n_frames,
                "latency_median_s": float(np.median(lat)) if lat.size else float("nan"),
                "latency_p90_s": float(np.percentile(lat, 90)) if lat.size else float("nan")}
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()


def bench_in_process_at_rate(rig, rate_hz: float, n_frames: int, tmp: Path, matcher: str = "elas",
                             segment: bool = True) -> dict:
    """The in-process graph (``canopy-stereo run``) fed the same frames at ``rate_hz``."""
    bag = make_bag(tmp / f"rate{rate_hz:g}.mcap", n_frames, fps=rate_hz)
    options = GraphOptions(matcher=matcher, segment=segment, parameter_services=False)
    run_bag(make_bag(tmp / "warm_rate.mcap", 2), rig, rate=0, options=options)
    result = run_bag(bag, rig, rate=1.0, options=options)
    lat = result.latencies_s
    import numpy as np

    return {"clouds_per_pair": result.frames_out / max(1, result.frames_in),
            "latency_median_s": result.latency_median_s,
            "latency_p90_s": float(np.percentile(lat, 90)) if lat else float("nan")}


def per_frame_busy(result) -> str:
    n = max(1, result.frames_in)
    return ", ".join(f"{name.replace('_node', '')} {st['busy_s'] / n * 1e3:.0f}"
                     for name, st in sorted(result.graph_stats.items()))


def legacy_main(args) -> int:
    """The replay (``--replay``) and issue-12 rate (``--processes``) modes."""
    rig = load_rig(bundled_rig("croton"))
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f}; "
          f"{args.frames} frames of {rig.image_size[0]}x{rig.image_size[1]} (paper rig)")
    with tempfile.TemporaryDirectory() as tmp:
        if args.processes or args.processes_only:
            print("multi-process (4 node processes, ELAS + GrabCut) vs in-process graph, fed at a fixed rate:")
            print(f"{'rate Hz':>8s} {'graph':14s} {'clouds/pair':>12s} {'latency median':>15s} {'p90':>8s}")
            for rate in args.rates:
                rows = [("processes", bench_processes(rate, args.frames, Path(tmp) / f"logs{rate:g}")),
                        ("in-process", bench_in_process_at_rate(rig, rate, args.frames, Path(tmp)))]
                for label, r in rows:
                    print(f"{rate:8.0f} {label:14s} {r['clouds_per_pair']:12.2f} "
                          f"{r['latency_median_s'] * 1e3:12.0f} ms {r['latency_p90_s'] * 1e3:5.0f} ms", flush=True)
            if args.processes_only:
                return 0
        bag = make_bag(Path(tmp) / "bench.mcap", args.frames)
        warm = make_bag(Path(tmp) / "warm.mcap", 2)
        print(f"{'executor':9s} {'matcher':8s} {'segment':8s} {'frames/s':>9s} {'latency median':>15s} "
              f"{'latency max':>12s}  busy ms/frame per node")
        for executor, matcher, segment in [(e, m, s) for e in args.executors for m in args.matchers
                                           for s in (True, False)]:
            options = GraphOptions(matcher=matcher, segment=segment, parameter_services=False,
                                   executor=executor)
            run_bag(warm, rig, rate=0, options=options)  # JIT caches, first-call costs
            thr = run_bag(bag, rig, rate=0, options=options, max_in_flight=2)
            lat = run_bag(bag, rig, rate=0, options=options, max_in_flight=1)
            print(f"{executor:9s} {matcher:8s} {str(segment):8s} {thr.fps:9.2f} "
                  f"{lat.latency_median_s * 1e3:12.0f} ms {max(lat.latencies_s) * 1e3:9.0f} ms  "
                  f"{per_frame_busy(thr)}", flush=True)
        if not args.no_cli:
            out = io.StringIO()
            with contextlib.redirect_stdout(out):
                cli_main(["run", "--bag", str(bag), "--rig", str(bundled_rig("croton")), "--rate", "0",
                          "--record", str(Path(tmp) / "out.mcap")])
            print("canopy-stereo run --rate 0 --record OUT.mcap (defaults: ELAS, segmentation):")
            for line in out.getvalue().splitlines():
                if not line.startswith("recorded"):
                    print("  " + line)
    return 0


# --------------------------------------------------------------------------- issue 15: per configuration

#: Configuration sizes -> scale of the source frames (a 640x480 window; 640x360 for 1280x720:
#: the middle rows of the window, as a 16:9 webcam mode sees the 4:3 sensor).
SIZES = {"320x240": 0.5, "640x480": 1.0, "1280x720": 2.0, "1280x960": 2.0}
MODES = ("processes", "inprocess")
MATCHERS = ("elas", "sgbm")
MASKS = ("mask", "nomask")
#: ``--quick``: the issue's graph (four processes, ELAS, the mask, 640x480) and the same in one process.
QUICK_CONFIGS = ("processes:elas:mask:640x480", "inprocess:elas:mask:640x480")
#: Input transports (TRANSPORT of a configuration).
TRANSPORTS = ("raw", "compressed")
#: The headline configurations with JPEG camera streams (``--compressed``).
COMPRESSED_CONFIGS = tuple(f"{c}:compressed" for c in QUICK_CONFIGS)
#: ``--hd``: issue 28's HD webcam graph, four processes at 1280x720, masked and not, raw and JPEG inputs.
HD_CONFIGS = tuple(f"processes:elas:{mask}:1280x720{transport}" for mask in MASKS for transport in ("", ":compressed"))
#: Crop of the 710x496 Plants pair to 640x480 (centre of the drift), pixels.
PLANTS_CROP = (35, 8)
#: Scenes whose frames are a drifting window of one real pair (the others: their frames, cycled).
DRIFTING_SCENES = ("plants", "aloe")
#: Drift of the crop window (pixels, each way) and its period (frames).
DRIFT_PX, DRIFT_PERIOD = (12, 6), 60
#: Standard deviation of the per-frame sensor noise (grey levels).
NOISE_SIGMA = 2.0
#: ``--lens``: how the pre-rectified real pairs (Plants, Aloe) reach the graph: ``webcam`` = as two
#: webcams would see them (:func:`webcam_lens`: each camera turned by a fraction of a degree, with
#: a webcam's barrel distortion, so that rectify_node undistorts and rectifies as on a real rig);
#: ``none`` = as published (identity rectification maps, which rectify_node does not resample).
LENSES = ("webcam", "none")
#: :func:`webcam_lens`: each camera's turn (rx, ry, rz in degrees: pitch, yaw, roll) and
#: distortion (plumb_bob k1, k2, p1, p2, k3 at the frame's own focal length).
WEBCAM_TURNS_DEG = ((0.4, -0.6, 0.3), (-0.3, 0.5, -0.4))
WEBCAM_DISTORTION = (-0.08, 0.02, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Config:
    """One benchmark configuration (see the module docstring)."""

    mode: str
    matcher: str
    mask: bool
    size: str
    transport: str = "raw"

    @classmethod
    def parse(cls, text: str) -> Config:
        """``MODE:MATCHER:MASK:SIZE[:TRANSPORT]`` -> Config (ValueError naming the bad part)."""
        parts = text.split(":")
        if len(parts) not in (4, 5):
            raise ValueError(f"configuration {text!r}: expected MODE:MATCHER:MASK:SIZE[:TRANSPORT], "
                             "e.g. processes:elas:mask:640x480")
        mode, matcher, mask, size = parts[:4]
        transport = parts[4] if len(parts) == 5 else "raw"
        for value, choices, what in ((mode, MODES, "mode"), (matcher, MATCHERS, "matcher"),
                                     (mask, MASKS, "mask"), (size, tuple(SIZES), "size"),
                                     (transport, TRANSPORTS, "transport")):
            if value not in choices:
                raise ValueError(f"configuration {text!r}: {what} must be one of {', '.join(choices)}")
        return cls(mode, matcher, mask == "mask", size, transport)

    def __str__(self) -> str:
        text = f"{self.mode}:{self.matcher}:{'mask' if self.mask else 'nomask'}:{self.size}"
        return text if self.transport == "raw" else f"{text}:{self.transport}"

    @property
    def nodes(self) -> tuple[str, ...]:
        base = ("rectify_node", "disparity_node", "segment_node", "point_cloud_node")
        return base if self.mask else tuple(n for n in base if n != "segment_node")


def all_configs() -> list[str]:
    """Every configuration, processes before in-process, 640x480 first."""
    sizes = ["640x480", "320x240", "1280x720", "1280x960"]
    return [f"{m}:{a}:{k}:{s}" for s in sizes for a in MATCHERS for k in MASKS for m in MODES]


def scaled_rig(rig, scale: float, crop=(0, 0), size=None):
    """``rig`` for images cropped at ``crop`` = (x0, y0) to ``size`` (default: the rest) and
    then resized by ``scale`` (``cv2.resize``: pixel centres ``u' = s u + (s - 1) / 2``); the
    rig's ``disp_min``/``disp_max`` follow the scale."""
    import numpy as np

    from canopy_stereo.io.rig import Rig

    x0, y0 = crop
    w, h = size or (rig.image_size[0] - x0, rig.image_size[1] - y0)
    s = float(scale)
    A = np.array([[s, 0.0, (s - 1) / 2 - s * x0], [0.0, s, (s - 1) / 2 - s * y0], [0.0, 0.0, 1.0]])
    extra = dict(rig.extra)
    if "disp_min" in extra:
        extra["disp_min"] = max(0, int(np.floor(extra["disp_min"] * s)))
    if "disp_max" in extra:
        extra["disp_max"] = int(np.ceil(extra["disp_max"] * s))
    return Rig(A @ rig.P_left, A @ rig.P_right, (round(w * s), round(h * s)), rig.world_unit,
               rig.D_left, rig.D_right, extra)


def webcam_lens(rig) -> tuple:
    """``(raw_rig, (map_left, map_right))``: ``rig`` (a pre-rectified pair's rig) as two webcams:
    each camera turned about its centre by :data:`WEBCAM_TURNS_DEG` and given
    :data:`WEBCAM_DISTORTION`; the maps (float32 (H, W, 2), for ``cv2.remap``) take a frame of
    ``rig`` to what the turned, distorting camera records (the pixel of each raw ray in the
    frame). Rectifying the raw frames with ``raw_rig`` gives the frames back (turned by the left
    camera's pitch: Fusiello keeps the left camera's optical axis in the plane it sets)."""
    import dataclasses

    import cv2
    import numpy as np

    from canopy_stereo.geometry.rig import Rig
    from canopy_stereo.geometry.rig_rectification import rectification_for_rig

    w, h = rig.image_size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    D = np.array(WEBCAM_DISTORTION)
    projections, maps = [], []
    for P, turn in ((rig.P_left, WEBCAM_TURNS_DEG[0]), (rig.P_right, WEBCAM_TURNS_DEG[1])):
        K, R, C = cv2.decomposeProjectionMatrix(P)[:3]
        K = K / K[2, 2]
        C = (C[:3] / C[3]).ravel()
        Q = cv2.Rodrigues(np.radians(np.array(turn, dtype=np.float64)))[0]
        projections.append(K @ np.hstack([Q @ R, (-Q @ R @ C)[:, None]]))
        rays = cv2.undistortPoints(pixels, K, D).reshape(-1, 2)  # the raw camera's ideal rays
        back = np.hstack([rays, np.ones((rays.shape[0], 1))]) @ Q  # rows: Q^T ray (the frame's camera)
        uv = back @ K.T
        maps.append((uv[:, :2] / uv[:, 2:]).reshape(h, w, 2).astype(np.float32))
    raw = Rig(projections[0], projections[1], rig.image_size, rig.world_unit, D, D, dict(rig.extra))
    # the frames' rig keeps its rectified principal points apart (doffs); the webcams' rectification
    # gives both one: the same points' disparities move by the difference
    shift = rectification_for_rig(raw).doffs - rectification_for_rig(rig).doffs
    extra = dict(rig.extra)
    if "disp_min" in extra:
        extra["disp_min"] = max(0, int(np.floor(extra["disp_min"] + shift)))
    if "disp_max" in extra:
        extra["disp_max"] = int(np.ceil(extra["disp_max"] + shift))
    return dataclasses.replace(raw, extra=extra), tuple(maps)


def bench_frames(scene: str, size: str, n_frames: int = DRIFT_PERIOD, seed: int = 0, *, lens: str = "none"):
    """``(rig, frames)``: the rig of ``size`` and ``n_frames`` (left, right) uint8 BGR pairs of
    the bundled ``scene`` (``plants``: the real Middlebury pair, a 640x480 crop drifting by
    :data:`DRIFT_PX`; ``croton``: the four synthetic frames, cycled), resized to ``size``, with
    fresh sensor noise (sigma :data:`NOISE_SIGMA`) in every frame. A 16:9 size (1280x720) sees
    the middle 640x360 rows of the 640x480 window, scaled (the rig follows: :func:`scaled_rig`).
    ``lens`` (:data:`LENSES`): ``webcam`` records the drifting real pairs through
    :func:`webcam_lens` (the rig is the webcams'), ``none`` leaves them pre-rectified."""
    if lens not in LENSES:
        raise ValueError(f"lens must be one of {', '.join(LENSES)}, got {lens!r}")
    import cv2
    import numpy as np

    if scene == "aloe":  # the held-out real plant, disparities to about 130 px (shared data)
        from test.support.aloe import ALOE_CROP, aloe_source

        rig, left, right = aloe_source()
        lefts, rights, crop = [left], [right], ALOE_CROP
    else:
        bag = BagReader(bundled_bag(scene))
        lefts = [msg_to_image(m).copy() for _, m in bag.read("/stereo/left/image_raw")]
        rights = [msg_to_image(m).copy() for _, m in bag.read("/stereo/right/image_raw")]
        rig, crop = load_rig(bundled_rig(scene)), PLANTS_CROP
    scale = SIZES[size]
    width, height = (int(v) for v in size.split("x"))
    ww, wh = round(width / scale), round(height / scale)  # the source window: 640x480 or 640x360
    rng = np.random.default_rng(seed)
    frames = []
    drifting = scene in DRIFTING_SCENES
    if drifting:
        (cx, cy), (dx, dy) = crop, DRIFT_PX
        cy += (480 - wh) // 2
        rig = scaled_rig(rig, scale, (cx, cy), (ww, wh))
        cx, cy = min(cx, lefts[0].shape[1] - ww - dx), min(cy, lefts[0].shape[0] - wh - dy)
    else:
        y0 = (rig.image_size[1] - wh) // 2
        rig = scaled_rig(rig, scale, (0, y0), (ww, wh)) if y0 else scaled_rig(rig, scale)
        lefts, rights = [im[y0:y0 + wh] for im in lefts], [im[y0:y0 + wh] for im in rights]
    lens_maps = None
    if drifting and lens == "webcam":
        rig, lens_maps = webcam_lens(rig)
    for k in range(n_frames):
        left, right = lefts[k % len(lefts)], rights[k % len(rights)]
        if drifting:
            phase = 2 * np.pi * k / DRIFT_PERIOD
            x = cx + int(round(dx * np.sin(phase)))
            y = cy + int(round(dy * np.sin(2 * phase)))
            left, right = left[y:y + wh, x:x + ww], right[y:y + wh, x:x + ww]
        pair = []
        for side, img in enumerate((left, right)):
            if scale != 1:
                img = cv2.resize(img, rig.image_size, interpolation=cv2.INTER_AREA if scale < 1
                                 else cv2.INTER_LINEAR)
            if lens_maps is not None:
                img = cv2.remap(img, lens_maps[side], None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
            noisy = img.astype(np.float32) + rng.normal(0.0, NOISE_SIGMA, img.shape).astype(np.float32)
            pair.append(np.clip(np.rint(noisy), 0, 255).astype(np.uint8))
        frames.append(tuple(pair))
    return rig, frames


CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def proc_cpu_seconds(pid: int | str = "self", tid: int | None = None) -> float:
    """User + system CPU seconds of a process (all its threads) or of one of its threads
    (``/proc/<pid>/stat`` or ``/proc/<pid>/task/<tid>/stat``, fields 14 and 15)."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    with open(path) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime (fields 14, 15)


def proc_peak_rss_mb(pid: int | str = "self") -> float:
    """Peak resident set (``VmHWM``) of a process in MB (NaN when unreadable)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return float("nan")


def thread_owner(name: str) -> str:
    """The node (or ``feed``/``dds``) a thread of the in-process graph works for, from its name:
    ``canopy_graph:<node>`` (executor), ``<node>:latest`` (LatestOnly worker), ``elas_<i>``
    (ELAS pool, the disparity node's), ``bench:*`` (feeder and probe)."""
    if name.startswith("canopy_graph:"):
        return name.split(":", 1)[1]
    if name.endswith(":latest"):
        return name.rsplit(":", 1)[0]
    if name.startswith("elas"):
        return "disparity_node"
    if name.startswith("bench:"):
        return "feed"
    return "dds"


def in_process_cpu_seconds() -> dict:
    """Owner (:func:`thread_owner`) -> CPU seconds of the threads of this process; threads not
    started by Python (the middleware's) and the main thread count as ``dds``/``feed``."""
    import threading

    out: dict = {}
    named = {}
    for t in threading.enumerate():
        if t.native_id is not None:
            named[t.native_id] = "feed" if t is threading.main_thread() else thread_owner(t.name)
    for entry in os.listdir("/proc/self/task"):
        tid = int(entry)
        try:
            cpu = proc_cpu_seconds("self", tid)
        except OSError:  # the thread ended meanwhile
            continue
        owner = named.get(tid, "dds")
        out[owner] = out.get(owner, 0.0) + cpu
    return out


class DiagnosticsTotals:
    """Latest ``out ... total`` and ``dropped total`` of every node on ``/diagnostics``."""

    def __init__(self, node):
        import threading

        from diagnostic_msgs.msg import DiagnosticArray

        self.lock = threading.Lock()
        self.latest: dict = {}
        self.reasons: dict = {}
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 50)

    def _on(self, msg) -> None:
        for status in msg.status:
            # "<namespace>/<node>: pipeline" (the namespace keeps two rigs apart): keyed by node name
            node = status.name.split(":", 1)[0].rsplit("/", 1)[-1]
            values = {kv.key: kv.value for kv in status.values}
            outs = [int(v) for k, v in values.items() if k.startswith("out ") and k.endswith(" total")]
            with self.lock:
                self.latest[node] = {"out": max(outs) if outs else 0,
                                     "dropped": int(values.get("dropped total", 0))}
                reasons = self.reasons.setdefault(node, collections.Counter())
                for k, v in values.items():  # each report's window: summed, the run's reasons
                    if k.startswith("dropped: "):
                        reasons[k[len("dropped: "):]] += int(v)

    def snapshot(self) -> dict:
        with self.lock:
            return {k: dict(v) for k, v in self.latest.items()}

    def reason_counts(self) -> dict:
        """node -> {drop reason: count} summed over the reports heard so far."""
        with self.lock:
            return {k: dict(v) for k, v in self.reasons.items()}


def parse_node_parameter(text: str) -> tuple[str, str, object]:
    """``NODE:NAME=VALUE`` (VALUE in YAML, as ``-p NAME:=VALUE``) -> ``(node, name, value)``."""
    import yaml

    node, sep, rest = text.partition(":")
    name, eq, value = rest.partition("=")
    if not sep or not eq or not node or not name:
        raise ValueError(f"node parameter {text!r}: expected NODE:NAME=VALUE, "
                         "e.g. disparity_node:elas.subsampling=true")
    return node, name, yaml.safe_load(value)


def run_config(config: Config, *, scene: str = "plants", n_frames: int = 90, rate_hz: float = 30.0,
               log_dir: Path, threads: int | None = None, node_parameters: dict | None = None,
               intra_process: bool = True, jpeg_quality: int = 95, stages: bool = False,
               lens: str = "webcam") -> dict:
    """Feed the graph of ``config`` ``n_frames`` pairs at ``rate_hz``; the figures (see the module
    docstring) as a dict. Runs in the calling process (``main`` gives each configuration a fresh one).
    ``stages``: also the median latency at which each stage's output arrives (:data:`STAGE_TOPICS`;
    the probe's extra subscriptions cost the publishers a copy each)."""
    import threading
    import time

    import numpy as np
    from sensor_msgs.msg import Image, PointCloud2

    from canopy_stereo.io.rig import save_rig
    from canopy_stereo.ros.context import private_domain_id
    from canopy_stereo.ros.convert import image_to_msg
    from canopy_stereo.ros.recorder import header_stamp_from_cdr

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's test package
    from test.support.ros_harness import Probe, ProcessGroup, wait_for

    rig, frames = bench_frames(scene, config.size, lens=lens)
    log_dir.mkdir(parents=True, exist_ok=True)
    rig_path = save_rig(rig, log_dir / "rig.yaml")
    domain = private_domain_id()
    params = {"disparity_node": {"matcher": config.matcher},
              "point_cloud_node": {"use_mask": config.mask}}
    if config.transport == "compressed":
        params["rectify_node"] = {"image_transport": "compressed"}
    if threads:
        params["disparity_node"]["threads"] = int(threads)
    for node, values in (node_parameters or {}).items():
        params.setdefault(node, {}).update(values)
    group = graph = probe = None
    arrivals: dict = {}
    lock = threading.Lock()
    try:
        probe = Probe(domain, name="bench_probe")
        probe._thread.name = "bench:probe"
        if config.mode == "processes":
            group = ProcessGroup(domain, log_dir)
            procs = group.start_graph(rig_path, nodes=config.nodes, params=params)
            pids = {name: p.pid for name, p in procs.items()}
        else:
            from canopy_stereo.ros.graph import CanopyGraph, GraphOptions

            in_graph = {node: {k: v for k, v in values.items() if (node, k) not in
                               (("disparity_node", "matcher"), ("point_cloud_node", "use_mask"))}
                        for node, values in params.items()}
            graph = CanopyGraph(rig, probe.context, GraphOptions(
                matcher=config.matcher, segment=config.mask, use_mask=config.mask,
                parameter_services=False, node_parameters=in_graph, intra_process=intra_process))
            graph.spin_in_background()
            pids = {}
        diagnostics = DiagnosticsTotals(probe.node)
        if config.transport == "compressed":  # JPEG from the cameras, as webcams deliver MJPEG
            from sensor_msgs.msg import CompressedImage

            from canopy_stereo.ros.compressed import image_to_compressed_msg

            pub_l = probe.publisher(CompressedImage, "left/image_raw/compressed")
            pub_r = probe.publisher(CompressedImage, "right/image_raw/compressed")

            def to_msg(image, frame_id):
                return image_to_compressed_msg(image, quality=jpeg_quality, frame_id=frame_id)
        else:
            pub_l = probe.publisher(Image, "left/image_raw")
            pub_r = probe.publisher(Image, "right/image_raw")

            def to_msg(image, frame_id):
                return image_to_msg(image, "bgr8", stamp_ns=0, frame_id=frame_id)

        def on_cloud(data):
            t = time.time_ns()
            stamp = header_stamp_from_cdr(data[:12])
            with lock:
                arrivals.setdefault(stamp, t)

        from rclpy.qos import QoSProfile, ReliabilityPolicy

        sub = probe.node.create_subscription(PointCloud2, "points2", on_cloud,
                                             QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
                                             raw=True)
        stage_arrivals: dict[str, dict] = {}
        if stages:
            from importlib import import_module

            for stage, (topic, type_name) in STAGE_TOPICS.items():
                if stage == "mask" and not config.mask:
                    continue
                package, _, name = type_name.rpartition(".")
                seen = stage_arrivals.setdefault(stage, {})

                def on_stage(data, seen=seen):
                    t = time.time_ns()
                    stamp = header_stamp_from_cdr(data[:12])
                    with lock:
                        seen.setdefault(stamp, t)

                probe.node.create_subscription(getattr(import_module(package), name), topic, on_stage,
                                               QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
                                               raw=True)
        if not wait_for(lambda: sub.get_publisher_count() >= 1 and pub_l.get_subscription_count() >= 1
                        and pub_r.get_subscription_count() >= 1, 60.0, group=group):
            raise RuntimeError("the graph did not connect" + (":\n" + group.logs() if group else ""))
        msgs = [(to_msg(left, "left_camera"), to_msg(right, "right_camera")) for left, right in frames]

        def publish(k: int) -> int:
            stamp = time.time_ns()
            left, right = msgs[k % len(msgs)]
            left.header.stamp.sec, left.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
            right.header.stamp.sec, right.header.stamp.nanosec = divmod(stamp + 4_000_000, 1_000_000_000)
            pub_l.publish(left)
            pub_r.publish(right)
            return stamp

        # warm-up: first-call costs (numba caches, buffers) at 2 Hz until clouds come, then at the
        # rate for a second, so that every node's allocations and queues are in steady state
        deadline = time.monotonic() + 120.0
        k = 0
        while not arrivals and time.monotonic() < deadline:
            publish(k)
            k += 1
            wait_for(lambda: bool(arrivals), 0.5, group=group)
        if not arrivals:
            raise RuntimeError("no cloud during the warm-up" + (":\n" + group.logs() if group else ""))
        for j in range(int(rate_hz)):
            publish(k + j)
            time.sleep(1.0 / rate_hz)
        time.sleep(2.5)  # drain, and one diagnostics period for the totals
        with lock:
            arrivals.clear()
            for seen in stage_arrivals.values():
                seen.clear()
        diag0 = diagnostics.snapshot()
        reasons0 = diagnostics.reason_counts()

        def cpu_now() -> dict:
            if pids:
                out = {name: proc_cpu_seconds(pid) for name, pid in pids.items()}
                out["feed"] = proc_cpu_seconds("self")
                return out
            return in_process_cpu_seconds()

        cpu0, wall0 = cpu_now(), time.monotonic()
        sent = []
        t0 = time.monotonic()
        for i in range(n_frames):
            delay = t0 + i / rate_hz - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            sent.append(publish(i))
        t_fed = time.monotonic()
        wanted = set(sent)
        last, last_n = time.monotonic(), 0
        while time.monotonic() - last < 2.0 and time.monotonic() - t_fed < 30.0:
            with lock:
                n = len(wanted & set(arrivals))
            if n == len(wanted):
                break
            if n != last_n:
                last, last_n = time.monotonic(), n
            time.sleep(0.05)
        cpu1, wall1 = cpu_now(), time.monotonic()
        time.sleep(1.3)  # the next diagnostics period
        diag1 = diagnostics.snapshot()
        reasons1 = diagnostics.reason_counts()
        with lock:
            got = {s: t for s, t in arrivals.items() if s in wanted}
        lat_ms = np.array([(got[s] - s) / 1e6 for s in sent if s in got])
        with lock:  # each stage's latency over the pairs that became clouds
            stage_ms = {stage: float(np.median([(seen[s] - s) / 1e6 for s in got if s in seen]))
                        for stage, seen in stage_arrivals.items() if any(s in seen for s in got)}
        feed_s = (sent[-1] - sent[0]) / 1e9 if len(sent) > 1 else float("nan")
        span_s = (max(got.values()) - sent[0]) / 1e9 if got else float("nan")
        nodes = {}
        for name in (*config.nodes, "dds", "feed"):
            if name not in cpu1 and name not in cpu0:
                continue
            row = {"cpu_ms_per_pair": (cpu1.get(name, 0.0) - cpu0.get(name, 0.0)) / n_frames * 1e3}
            if name in diag1:
                row["out"] = diag1[name]["out"] - diag0.get(name, {}).get("out", 0)
                row["dropped"] = diag1[name]["dropped"] - diag0.get(name, {}).get("dropped", 0)
                before = reasons0.get(name, {})
                row["drop_reasons"] = {k: n - before.get(k, 0) for k, n in reasons1.get(name, {}).items()
                                       if n - before.get(k, 0) > 0}
            if name in pids:
                row["rss_peak_mb"] = proc_peak_rss_mb(pids[name])
            nodes[name] = row
        return {
            "config": str(config), "scene": scene, "lens": lens, "frames": n_frames, "rate_hz": rate_hz,
            "offered_per_s": (len(sent) - 1) / feed_s if feed_s > 0 else float("nan"),
            "delivered_per_s": len(got) / span_s if got and span_s > 0 else 0.0,
            "delivered_fraction": len(got) / len(sent),
            "latency_median_ms": float(np.median(lat_ms)) if lat_ms.size else float("nan"),
            "latency_p95_ms": float(np.percentile(lat_ms, 95)) if lat_ms.size else float("nan"),
            "cpu_window_s": wall1 - wall0,
            "process_rss_peak_mb": proc_peak_rss_mb("self"),
            "nodes": nodes,
            "stage_latency_ms": stage_ms,
        }
    finally:
        if graph is not None:
            graph.shutdown()
        if probe is not None:
            probe.close()
        if group is not None:
            group.stop_all()


def _short(name: str) -> str:
    return name.replace("_node", "").replace("point_cloud", "cloud")


def format_result(r: dict) -> list[str]:
    """Two lines per configuration: rates and latency; then CPU ms/pair, outputs, drops, RSS per node."""
    lines = [f"{r['config']:32s} {r['offered_per_s']:7.1f} {r['delivered_per_s']:9.1f} "
             f"{r['delivered_fraction'] * 100:5.0f}% {r['latency_median_ms']:8.0f} {r['latency_p95_ms']:6.0f}  "
             f"cpu {sum(v['cpu_ms_per_pair'] for k, v in r['nodes'].items() if k != 'feed'):5.1f} ms/pair"]
    parts = []
    for name, v in r["nodes"].items():
        text = f"{_short(name)} {v['cpu_ms_per_pair']:.1f}"
        if "out" in v:
            per_out = v["cpu_ms_per_pair"] * r["frames"] / v["out"] if v["out"] else float("nan")
            text += f" ({per_out:.1f}/out; out {v['out']}, drop {v['dropped']})"
        if "rss_peak_mb" in v:
            text += f" {v['rss_peak_mb']:.0f} MB"
        parts.append(text)
    if r["config"].startswith("inprocess"):
        parts.append(f"process {r['process_rss_peak_mb']:.0f} MB")
    lines.append("    cpu ms per offered pair (per frame output): " + ", ".join(parts))
    if r.get("stage_latency_ms"):
        lines.append("    latency p50 of the clouds' pairs at each stage's output: "
                     + ", ".join(f"{k} {v:.0f} ms" for k, v in r["stage_latency_ms"].items()))
    for name, v in r["nodes"].items():
        top = sorted(v.get("drop_reasons", {}).items(), key=lambda kv: -kv[1])[:3]
        if top:
            lines.append(f"    {_short(name)} drops: " + "; ".join(f"{n}x {k[:90]}" for k, n in top))
    return lines


#: ``--stages``: stage -> (topic, message type) whose arrival times the probe records
STAGE_TOPICS = {"rectify": ("left/image_rect/camera_info", "sensor_msgs.msg.CameraInfo"),
                "disparity": ("disparity", "stereo_msgs.msg.DisparityImage"),
                "mask": ("left/mask", "sensor_msgs.msg.Image")}

HEADER = (f"{'configuration':32s} {'offered':>7s} {'delivered':>9s} {'ratio':>6s} {'lat p50':>8s} "
          f"{'p95':>6s}  (clouds/s, ms)")


#: ``--foreign-driver`` receive buffers: the package's (4 MiB, needs ``net.core.rmem_max`` >= 4 MiB) and
#: what a stock kernel's ``rmem_max`` (208 kB) caps it to.
RECEIVE_BUFFERS = {"4MiB (rmem_max >= 4 MiB)": 4194304, "208kB (stock rmem_max)": 212992}


def bench_foreign_driver(rate_hz: float, n_frames: int, log_dir: Path, *, scene: str = "plants",
                         receive_buffer: int = 4194304, nodes=("rectify_node", "disparity_node",
                                                               "point_cloud_node")) -> dict:
    """The node processes fed by a driver that is not ours (``test/support/foreign_driver.py``: a
    process on Fast DDS's defaults, 640x480 bgr8 pairs stamped at publication) at ``rate_hz``; the
    node processes' profile is the package's with the UDP receive buffer set to ``receive_buffer``
    (the kernel caps it at ``net.core.rmem_max``: 208 kB stands for a stock kernel). Returns clouds
    per pair, clouds/s delivered and latency (publication to cloud arrival) median and p95."""
    import json
    import subprocess
    import time

    import numpy as np
    from sensor_msgs.msg import PointCloud2

    from canopy_stereo.io.rig import save_rig
    from canopy_stereo.ros.context import FASTDDS_PROFILES, private_domain_id

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the checkout's test package
    from test.support.foreign_driver import foreign_env
    from test.support.ros_harness import Probe, ProcessGroup, wait_for

    log_dir.mkdir(parents=True, exist_ok=True)
    rig, _ = bench_frames(scene, "640x480", n_frames=1)
    rig_path = save_rig(rig, log_dir / "rig.yaml")
    profile = log_dir / "fastdds_profiles.xml"
    profile.write_text(FASTDDS_PROFILES.read_text().replace(
        "<receiveBufferSize>4194304</receiveBufferSize>",
        f"<receiveBufferSize>{int(receive_buffer)}</receiveBufferSize>"))
    group = ProcessGroup(private_domain_id(), log_dir)
    group.env.update(FASTRTPS_DEFAULT_PROFILES_FILE=str(profile), RMW_FASTRTPS_USE_QOS_FROM_XML="1")
    probe = None
    try:
        group.start_graph(rig_path, nodes=nodes)
        probe = Probe(group.domain_id, name="bench_probe")
        clouds = probe.subscribe(PointCloud2, "points2")
        inputs = {"/stereo/left/image_raw": 1, "/stereo/right/image_raw": 1, "/stereo/disparity": 1,
                  "/stereo/left/image_rect": 1, "/stereo/left/image_rect_color": 1}
        if not wait_for(lambda: all(probe.node.count_subscribers(t) >= n for t, n in inputs.items())
                        and clouds.subscription.get_publisher_count() >= 1, 300.0, group=group):
            raise RuntimeError("the node processes did not connect:\n" + group.logs())
        driver = subprocess.run([sys.executable, "-m", "test.support.foreign_driver", "--rate", str(rate_hz),
                                 "--frames", str(n_frames), "--scene", scene],
                                cwd=Path(__file__).resolve().parents[1], env=foreign_env(group.env),
                                capture_output=True, text=True, timeout=600)
        if driver.returncode != 0:
            raise RuntimeError(f"the driver failed: {driver.stderr[-2000:]}")
        out = json.loads(driver.stdout.strip().splitlines()[-1])
        sent = {int(k): t for k, t in out["sent"].items()}
        time.sleep(1.0)
        with clouds.lock:
            got = {s: t for t, s, _ in clouds.items if s in sent}
        lat = np.array([got[s] - sent[s] for s in got]) * 1e3
        span = (max(got.values()) - min(sent.values())) if got else float("nan")
        return {"pairs": len(sent), "clouds": len(got), "clouds_per_s": len(got) / span if got else 0.0,
                "offered_per_s": (len(sent) - 1) / (max(sent.values()) - min(sent.values())),
                "latency_median_ms": float(np.median(lat)) if lat.size else float("nan"),
                "latency_p95_ms": float(np.percentile(lat, 95)) if lat.size else float("nan")}
    finally:
        if probe is not None:
            probe.close()
        group.stop_all()


def foreign_driver_main(args) -> int:
    """``--foreign-driver``: the graph fed by a driver on Fast DDS's defaults, with the package's
    receive buffer and with what a stock ``rmem_max`` leaves of it."""
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f}; a driver on Fast DDS's "
          f"defaults, {args.scene} 640x480 bgr8 at {args.rate:g} pairs/s, {args.frames} pairs; rectify, ELAS, "
          "point_cloud as processes", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for label, size in RECEIVE_BUFFERS.items():
            r = bench_foreign_driver(args.rate, args.frames, Path(tmp) / str(size), scene=args.scene,
                                     receive_buffer=size)
            print(f"receive buffer {label:26s}: {r['clouds']}/{r['pairs']} clouds, {r['clouds_per_s']:.1f} of "
                  f"{r['offered_per_s']:.1f} clouds/s, latency median {r['latency_median_ms']:.0f} ms, "
                  f"p95 {r['latency_p95_ms']:.0f} ms", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    return 0


def main(argv=None) -> int:
    import json
    import subprocess

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--configs", nargs="+", metavar="MODE:MATCHER:MASK:SIZE",
                   help="configurations to run (default: all 32; see the module docstring)")
    p.add_argument("--quick", action="store_true", help=f"only {' and '.join(QUICK_CONFIGS)}")
    p.add_argument("--compressed", action="store_true",
                   help=f"only {' and '.join(COMPRESSED_CONFIGS)} (JPEG camera streams)")
    p.add_argument("--hd", action="store_true",
                   help=f"only the 1280x720 graph: {', '.join(HD_CONFIGS)} (issue 28)")
    p.add_argument("--jpeg-quality", type=int, default=95, help="JPEG quality of compressed inputs (default 95)")
    p.add_argument("--scene", choices=("plants", "croton", "aloe"), default="plants",
                   help="frames: the real Middlebury Plants pair (default, disparities 0-81), the synthetic "
                        "croton, or the held-out real Aloe (disparities to about 130 px; needs ../shared/data)")
    p.add_argument("--rate", type=float, default=30.0, help="camera rate (pairs/s)")
    p.add_argument("--frames", type=int, default=None,
                   help="pairs fed per configuration (default 90; the --replay/--processes modes: 40)")
    p.add_argument("--threads", type=int, default=None,
                   help="disparity_node's thread budget (default: the node's)")
    p.add_argument("--param", action="append", default=[], metavar="NODE:NAME=VALUE",
                   help="a node parameter for every configuration (repeatable), e.g. "
                        "disparity_node:elas.subsampling=true, segment_node:recut_every=1")
    p.add_argument("--repeat", type=int, default=1, metavar="N",
                   help="run every configuration N times (rounds over all of them, so that a passing load "
                        "spreads over all) and print the median of each figure per configuration")
    p.add_argument("--json", metavar="OUT.json", help="also write the results as JSON")
    p.add_argument("--lens", choices=LENSES, default="webcam",
                   help="the real pairs (plants, aloe) as two webcams record them (default: turned cameras with "
                        "barrel distortion, which rectify_node undistorts and rectifies) or pre-rectified "
                        "(none: identity maps, which rectify_node does not resample)")
    p.add_argument("--stages", action="store_true",
                   help="also the median latency of each stage's output (rectified camera_info, disparity, "
                        "mask) for the pairs that became clouds; the probe's subscriptions add copies")
    p.add_argument("--no-intra-process", action="store_true",
                   help="inprocess: DDS between the nodes too (GraphOptions.intra_process=False)")
    p.add_argument("--one", metavar="CONFIG", help=argparse.SUPPRESS)  # one configuration, this process
    p.add_argument("--replay", action="store_true", help="the bag replay mode (frames/s as fast as possible)")
    p.add_argument("--matchers", nargs="*", default=["elas", "sgbm"], help="--replay: matchers")
    p.add_argument("--executors", nargs="*", default=["per-node"], choices=["per-node", "multi"],
                   help="--replay: executor layouts")
    p.add_argument("--no-cli", action="store_true", help="--replay: skip the CLI run")
    p.add_argument("--processes", action="store_true",
                   help="issue 12's comparison (4 node processes vs in-process, croton, at --rates), then --replay")
    p.add_argument("--processes-only", action="store_true", help="only issue 12's comparison")
    p.add_argument("--rates", nargs="*", type=float, default=[15.0, 30.0],
                   help="--processes: feeding rates (Hz)")
    p.add_argument("--foreign-driver", action="store_true",
                   help="the node processes fed by a driver on Fast DDS's defaults (issue 29), with the "
                        "package's 4 MiB receive buffer and with a stock rmem_max's 208 kB")
    args = p.parse_args(argv)
    if args.foreign_driver:
        args.frames = args.frames or 300
        return foreign_driver_main(args)
    if args.replay or args.processes or args.processes_only:
        args.frames = args.frames or 40
        return legacy_main(args)
    n_frames = args.frames or 90
    try:
        named = args.configs or (QUICK_CONFIGS if args.quick else COMPRESSED_CONFIGS if args.compressed
                                 else HD_CONFIGS if args.hd else all_configs())
        configs = [Config.parse(c) for c in named]
        if args.one:
            configs = [Config.parse(args.one)]
        node_parameters: dict = {}
        for text in args.param:
            node, name, value = parse_node_parameter(text)
            node_parameters.setdefault(node, {})[name] = value
    except ValueError as exc:
        p.error(str(exc))
    if args.one:
        with tempfile.TemporaryDirectory() as tmp:
            result = run_config(configs[0], scene=args.scene, n_frames=n_frames, rate_hz=args.rate,
                                log_dir=Path(tmp), threads=args.threads, node_parameters=node_parameters,
                                intra_process=not args.no_intra_process, jpeg_quality=args.jpeg_quality,
                                stages=args.stages, lens=args.lens)
        Path(args.json).write_text(json.dumps(result))
        return 0
    print(f"machine: {os.cpu_count()} CPU(s), load average {os.getloadavg()[0]:.2f} at start; "
          f"{args.scene} frames ({'as webcams record them' if args.lens == 'webcam' else 'pre-rectified'}), "
          f"{n_frames} pairs per configuration at {args.rate:g} pairs/s"
          + "".join(f"; {t}" for t in args.param) + (f"; disparity threads {args.threads}" if args.threads else "")
          + ("; in-process graph without the intra-process bus" if args.no_intra_process else ""),
          flush=True)
    print(HEADER, flush=True)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for config in [c for _ in range(max(1, args.repeat)) for c in configs]:
            out = Path(tmp) / f"{str(config).replace(':', '_')}.json"
            cmd = [sys.executable, str(Path(__file__).resolve()), "--one", str(config), "--json", str(out),
                   "--scene", args.scene, "--rate", str(args.rate), "--frames", str(n_frames),
                   "--jpeg-quality", str(args.jpeg_quality), "--lens", args.lens]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            if args.no_intra_process:
                cmd.append("--no-intra-process")
            if args.stages:
                cmd.append("--stages")
            for text in args.param:
                cmd += ["--param", text]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            if proc.returncode != 0 or not out.is_file():
                print(f"{str(config):32s} failed: {(proc.stderr or proc.stdout).strip().splitlines()[-1:]}",
                      flush=True)
                continue
            r = json.loads(out.read_text())
            results.append(r)
            print("\n".join(format_result(r)), flush=True)
    if args.repeat > 1:
        print(f"median of {args.repeat} runs per configuration:")
        for line in repeat_summary(results):
            print(line)
    print(f"load average {os.getloadavg()[0]:.2f} at the end (CPU ms per pair is the load-robust figure)")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0 if len(results) == len(configs) * max(1, args.repeat) else 1


def repeat_summary(results: list[dict]) -> list[str]:
    """One line per configuration of ``results`` (several runs each): the median delivered
    clouds/s (with the runs' range), latency p50 and p95, and CPU ms per offered pair."""
    import numpy as np

    by_config: dict[str, list[dict]] = {}
    for r in results:
        by_config.setdefault(r["config"], []).append(r)
    lines = []
    for name, runs in by_config.items():
        delivered = [r["delivered_per_s"] for r in runs]
        cpu = [sum(v["cpu_ms_per_pair"] for k, v in r["nodes"].items() if k != "feed") for r in runs]
        lines.append(f"{name:32s} {np.median([r['offered_per_s'] for r in runs]):7.1f} {np.median(delivered):9.1f} "
                     f"({min(delivered):.1f}-{max(delivered):.1f}) "
                     f"{np.median([r['latency_median_ms'] for r in runs]):8.0f} "
                     f"{np.median([r['latency_p95_ms'] for r in runs]):6.0f}  cpu {np.median(cpu):5.1f} ms/pair")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
