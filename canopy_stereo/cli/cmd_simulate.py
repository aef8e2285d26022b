"""``canopy-stereo simulate SCENE -o DIR``: render a synthetic scene with exact ground truth.

Writes into ``DIR`` (one frame), or into ``DIR/frame_0000``, ``DIR/frame_0001``,
... (``--frames N`` > 1, the leaves swaying gently from frame to frame):

* ``left.png``, ``right.png``: the stereo pair (8-bit colour);
* ``xyz_left.npy``, ``xyz_right.npy``: float64 (H, W, 3) world point seen at each
  pixel centre, NaN where nothing (rig world frame and unit);
* ``leaf_ids_left.png``, ``leaf_ids_right.png``: 16-bit leaf id per pixel, 0 = no leaf;
* ``truth.json``: scene, seed, frame, unit, background, leaves (id, length, width,
  chords, area, pose, visible pixels) -- see :mod:`canopy_stereo.sim`;

and ``DIR/rig.yaml``, a copy of the rig file used (default ``config/paper_rig.yaml``).

A field sequence (any of ``--motion``, ``--turn``, ``--skew``, ``--jitter``, ``--wind``,
``--fps``, ``--jpeg-quality``, ``--bag``, the gains or white balances): the rig moves past
the plants (``--motion along|across|toward --speed M/S``: along the baseline, across it
(up), toward the plants; ``--turn DEG/S``), leaves sway in wind of ``--wind`` strength (0
still, 1 the gentle breeze of plain ``--frames``, default), each camera captures at its own
times (``--fps``, right camera ``--skew MS`` later, ``--jitter MS``), with its own gain and
white balance, through MJPEG at ``--jpeg-quality``. Each frame folder's truth is the left
camera's at its capture instant (plus ``t_left``, ``t_right``, ``skew_ms``, ``rig_pose``,
``leaf_speed_mm_s``). ``--bag OUT.mcap`` also writes the frames as a rosbag2 bag stamped with
the capture times: raw ``/stereo/{left,right}/image_raw`` or, with ``--compressed``, JPEG
``.../image_raw/compressed``, plus ``/truth/left/depth`` (16UC1 mm) and the rig (needs rclpy).

``canopy-stereo simulate calibration -o DIR`` renders the paper's world-rig
calibration instead (the chessboard at each of the 45 places of the paper's
layout, on the floor sheet, 0.7 px blur, noise sigma 2 grey levels; or the
places of ``--placements FILE``): ``DIR/left_NN.png``, ``DIR/right_NN.png``,
``DIR/placements.yaml`` and ``DIR/rig.yaml`` (the true rig), ready for
``canopy-stereo calibrate --world-rig DIR/placements.yaml "DIR/left_*.png"
"DIR/right_*.png" -o rig.yaml``.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from canopy_stereo.cli.common import check_at_least
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import write_image
from canopy_stereo.io.rig import load_rig

COMMAND = "simulate"
HELP = "render a synthetic plant scene through a rig, with exact ground truth"
DESCRIPTION = __doc__.split("\n\n", 1)[1].strip()

#: Largest --supersample (n x n samples per pixel): 8 already renders 64 samples per pixel.
MAX_SUPERSAMPLE = 8


def add_arguments(parser) -> None:
    # scene names are checked by canopy_stereo.sim.build_scene (not imported here: it loads numba)
    parser.add_argument("scene", metavar="SCENE",
                        help="scene name: croton, citrus_branch or seedling_tray; or calibration "
                             "(the paper's world-rig calibration images + placements)")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--rig", metavar="RIG.yaml", default=None,
                        help="rig file (default: config/paper_rig.yaml, the paper's rig)")
    parser.add_argument("--seed", type=int, default=0, help="scene variation (default 0)")
    parser.add_argument("--frames", type=int, default=1,
                        help="number of frames; > 1 sways the leaves in a gentle breeze")
    parser.add_argument("--supersample", type=int, default=2,
                        help="anti-aliasing: 1 = pixel centres only, 2 = 4 samples per "
                             "pixel (default), n = n x n")
    parser.add_argument("--clean", action="store_true",
                        help="ideal sensors: no noise, vignetting or gain difference")
    parser.add_argument("--views", type=int, default=1, metavar="N",
                        help="multi-view sequence: N views round the plant with true poses, written as "
                             "DIR/view_XX/{left,right,mask}.png + rig.yaml and DIR/poses_true.yaml "
                             "(input of canopy-stereo fuse)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--turntable", dest="mode", action="store_const", const="turntable",
                      help="with --views: the plant turns on a turntable in front of the rig (default)")
    mode.add_argument("--orbit", dest="mode", action="store_const", const="orbit",
                      help="with --views: the rig circles the plant, looking down on it")
    parser.add_argument("--elevation", type=float, default=None, metavar="DEG",
                        help="with --orbit: how far the rig looks down (default 20 degrees)")
    seq = parser.add_argument_group("field sequence (a moving rig, wind, each camera's clock, MJPEG)")
    seq.add_argument("--motion", choices=("still", "along", "across", "toward"), default=None,
                     help="rig motion: along the baseline, across it (up) or toward the plants (needs --speed)")
    seq.add_argument("--speed", type=float, default=0.0, metavar="M/S", help="rig speed (default 0)")
    seq.add_argument("--turn", type=float, default=0.0, metavar="DEG/S",
                     help="rig turning rate about its vertical axis (default 0)")
    seq.add_argument("--fps", type=float, default=None, metavar="HZ", help="frame rate of both cameras (default 15)")
    seq.add_argument("--skew", type=float, default=None, metavar="MS",
                     help="the right camera captures MS later than the left (negative: earlier; default 0)")
    seq.add_argument("--jitter", type=float, default=None, metavar="MS",
                     help="capture-time jitter (standard deviation) of each camera (default 0)")
    seq.add_argument("--wind", type=float, default=None, metavar="STRENGTH",
                     help="wind strength: 0 still, 1 gentle breeze (default), 3 strong; leaf speed ~ STRENGTH^2")
    seq.add_argument("--gain-left", type=float, default=None, metavar="G", help="left camera gain (default 1)")
    seq.add_argument("--gain-right", type=float, default=None, metavar="G", help="right camera gain (default 0.93)")
    seq.add_argument("--white-balance-left", default=None, metavar="R,G,B",
                     help="left camera white balance gains (default 1,1,1)")
    seq.add_argument("--white-balance-right", default=None, metavar="R,G,B",
                     help="right camera white balance gains (default 1,1,1)")
    seq.add_argument("--jpeg-quality", type=int, default=None, metavar="Q",
                     help="MJPEG quality 1-100 of both cameras (default: lossless; 90 with --compressed)")
    seq.add_argument("--bag", metavar="OUT.mcap", default=None,
                     help="also write the sequence as a bag stamped with the capture times (needs rclpy)")
    seq.add_argument("--compressed", action="store_true",
                     help="with --bag: JPEG sensor_msgs/CompressedImage on <topic>/compressed")
    cal = parser.add_argument_group("calibration scene")
    cal.add_argument("--placements", metavar="PLACEMENTS.yaml", default=None,
                     help="board placements to render (default: the paper's layout in front of the rig)")
    cal.add_argument("--blur", type=float, default=0.7, metavar="PX",
                     help="Gaussian optical blur, sigma in pixels (default 0.7)")
    cal.add_argument("--noise", type=float, default=2.0, metavar="DN",
                     help="sensor noise sigma in grey levels (default 2; --clean: 0)")
    cal.add_argument("--samples", type=int, default=16, metavar="N",
                     help="anti-aliasing rays per pixel, lattice pattern (default 16)")


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_frame(sim, folder: Path) -> None:
    """Write one rendered frame's files into ``folder`` (a :class:`~canopy_stereo.sim.SimResult`
    or a :class:`~canopy_stereo.sim.sequence.SequenceFrame`)."""
    folder.mkdir(parents=True, exist_ok=True)
    write_image(folder / "left.png", sim.left)
    write_image(folder / "right.png", sim.right)
    np.save(folder / "xyz_left.npy", sim.xyz_left)
    np.save(folder / "xyz_right.npy", sim.xyz_right)
    write_image(folder / "leaf_ids_left.png", sim.leaf_ids_left.astype(np.uint16))
    write_image(folder / "leaf_ids_right.png", sim.leaf_ids_right.astype(np.uint16))
    (folder / "truth.json").write_text(json.dumps(sim.truth, indent=1, default=_json_default),
                                       encoding="utf-8")


def run(args) -> int:
    from canopy_stereo.sim import CLEAN, default_rig_path, render_pair, scene_for_rig

    if args.frames < 1:
        raise CanopyStereoError(f"--frames must be at least 1, got {args.frames}")
    if args.seed < 0:
        raise CanopyStereoError(f"--seed must be >= 0, got {args.seed}")
    check_at_least(args.views, 1, "--views")
    check_at_least(args.supersample, 1, "--supersample")
    if args.supersample > MAX_SUPERSAMPLE:
        raise CanopyStereoError(f"--supersample must be at most {MAX_SUPERSAMPLE} "
                                f"({MAX_SUPERSAMPLE}x{MAX_SUPERSAMPLE} samples per pixel), got {args.supersample}")
    if args.elevation is not None and not -90.0 < args.elevation < 90.0:
        raise CanopyStereoError(f"--elevation must be between -90 and 90 degrees, got {args.elevation}")
    rig_path = Path(args.rig) if args.rig else default_rig_path()
    rig = load_rig(rig_path)
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise CanopyStereoError(f"output {out} exists and is not a folder")
    if args.scene == "calibration":
        return _run_calibration(args, rig, rig_path, out)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(rig_path, out / "rig.yaml")
    effects = CLEAN if args.clean else None
    if args.views > 1 or args.mode is not None:
        return _run_views(args, rig, out, effects)
    if _is_sequence(args):
        return _run_sequence(args, rig, out, effects)
    for frame in range(args.frames):
        scene = scene_for_rig(args.scene, rig, seed=args.seed, frame=frame)
        sim = render_pair(scene, rig, supersample=args.supersample, effects=effects)
        folder = out if args.frames == 1 else out / f"frame_{frame:04d}"
        write_frame(sim, folder)
        leaves = sim.truth["leaves"]
        seen = sum(1 for lf in leaves if lf["pixels_left"] > 0)
        render_s = sim.timings.get("left", 0.0) + sim.timings.get("right", 0.0)
        print(f"{folder}: {args.scene} seed {args.seed} frame {frame}: {len(leaves)} leaves "
              f"({seen} visible in the left view), rendered in {render_s:.2f} s")
    return 0


_SEQUENCE_OPTIONS = ("motion", "fps", "skew", "jitter", "wind", "gain_left", "gain_right", "white_balance_left",
                     "white_balance_right", "jpeg_quality", "bag")


def _is_sequence(args) -> bool:
    return any(getattr(args, name) is not None for name in _SEQUENCE_OPTIONS) or args.compressed \
        or args.speed != 0 or args.turn != 0


def _gains(text: str | None, name: str):
    if text is None:
        return (1.0, 1.0, 1.0)
    try:
        gains = tuple(float(v) for v in text.split(","))
    except ValueError:
        gains = ()
    if len(gains) != 3 or not all(g > 0 and np.isfinite(g) for g in gains):
        raise CanopyStereoError(f"{name} must be three positive numbers R,G,B, got {text!r}")
    return gains


def _sequence_spec(args, effects):
    """The :class:`~canopy_stereo.sim.sequence.SequenceSpec` of the command line."""
    from dataclasses import replace

    from canopy_stereo.sim import CameraEffects
    from canopy_stereo.sim.sequence import CaptureTiming, RigMotion, SequenceSpec

    motion = args.motion or ("along" if args.speed else "still")
    if motion != "still" and not args.speed > 0:
        raise CanopyStereoError(f"--motion {motion} needs --speed M/S > 0")
    if motion == "still" and args.speed:
        raise CanopyStereoError("--speed needs --motion along, across or toward")
    jpeg = args.jpeg_quality if args.jpeg_quality is not None else (90 if args.compressed else None)
    if args.compressed and args.bag is None:
        raise CanopyStereoError("--compressed needs --bag OUT.mcap")
    effects = effects or CameraEffects()
    effects = replace(effects, **{k: v for k, v in (("gain_left", args.gain_left), ("gain_right", args.gain_right))
                                  if v is not None},
                      white_balance_left=_gains(args.white_balance_left, "--white-balance-left"),
                      white_balance_right=_gains(args.white_balance_right, "--white-balance-right"))
    return SequenceSpec(scene=args.scene, seed=args.seed, frames=args.frames,
                        motion=RigMotion(motion, float(args.speed), float(args.turn)),
                        timing=CaptureTiming(fps=15.0 if args.fps is None else float(args.fps),
                                             skew=(args.skew or 0.0) / 1e3, jitter=(args.jitter or 0.0) / 1e3),
                        wind=1.0 if args.wind is None else float(args.wind), effects=effects,
                        jpeg_quality=jpeg, supersample=args.supersample)


def _run_sequence(args, rig, out: Path, effects) -> int:
    """A field sequence (moving rig, wind, capture times, MJPEG): frame folders and an optional bag."""
    from canopy_stereo.sim.sequence import render_sequence

    spec = _sequence_spec(args, effects)
    if args.bag is not None:
        from canopy_stereo.ros import require_ros

        require_ros("canopy-stereo simulate --bag")
    frames, jpegs, depths = [], [], []
    epoch_ns = 1_704_067_200_000_000_000  # 2024-01-01T00:00:00Z, as the bundled bags
    for f in render_sequence(spec, rig):
        folder = out / f"frame_{f.index:04d}"
        write_frame(f, folder)
        print(f"{folder}: {args.scene} seed {args.seed} frame {f.index}: left at {f.t_left * 1e3:.1f} ms, "
              f"right at {f.t_right * 1e3:.1f} ms (skew {f.truth['skew_ms']:.1f} ms), "
              f"leaves up to {f.truth['leaf_speed_mm_s']['max']:.0f} mm/s", flush=True)
        if args.bag is not None:
            frames.append((f.left, f.right, epoch_ns + round(f.t_left * 1e9), epoch_ns + round(f.t_right * 1e9)))
            jpegs.append((f.jpeg_left, f.jpeg_right))
            depths.append(f.depth_left(rig) * rig.metres_per_unit)
    if args.bag is not None:
        from canopy_stereo.ros.bundled import write_stereo_bag

        bag = write_stereo_bag(args.bag, frames, truth_depths=depths, rig=rig,
                               metadata={"simulated": spec.scene, "motion": spec.motion.direction},
                               jpegs=jpegs if args.compressed else None)
        kind = "compressed (JPEG)" if args.compressed else "raw"
        print(f"{bag}: {len(frames)} {kind} stereo frames stamped with their capture times + /truth/left/depth")
    return 0


def _run_views(args, rig, out: Path, effects) -> int:
    """``--views N [--turntable | --orbit]``: a multi-view sequence with true poses."""
    from canopy_stereo.sim.multiview import render_views, write_views

    if args.views < 2:
        raise CanopyStereoError(f"--views must be at least 2 for a sequence, got {args.views}")
    if args.frames != 1:
        raise CanopyStereoError("--views and --frames cannot be combined")
    mode = args.mode or "turntable"
    if args.elevation is not None and mode != "orbit":
        raise CanopyStereoError("--elevation needs --orbit (a turntable's rig does not move)")
    from canopy_stereo.progress import Progress

    with Progress(args.views, f"rendering {args.scene} view") as bar:
        seq = render_views(args.scene, rig, n_views=args.views, mode=mode, seed=args.seed,
                           elevation_deg=args.elevation, supersample=args.supersample, effects=effects,
                           progress=bar.step)
    write_views(seq, out)
    for v in seq.views:
        seen = int((v.sim.leaf_ids_left > 0).sum())
        print(f"{out / v.name}: {args.scene} seed {args.seed} {mode} view {v.index} of {args.views}: "
              f"{seen} leaf pixels in the left view")
    print(f"true poses: {out / 'poses_true.yaml'} (fuse with: canopy-stereo fuse {out}/view_* -o fused.ply "
          f"[--poses {out / 'poses_true.yaml'}])")
    return 0


def _run_calibration(args, rig, rig_path: Path, out: Path) -> int:
    """``simulate calibration``: the paper's world-rig calibration images and placements."""
    from canopy_stereo.io.placements import load_placements, write_placements
    from canopy_stereo.sim.calibration import calibration_placements, render_calibration_scene

    if args.views != 1 or args.mode is not None or args.frames != 1:
        raise CanopyStereoError("the calibration scene has no --views, --turntable/--orbit or --frames")
    if not args.blur >= 0:
        raise CanopyStereoError(f"--blur must be >= 0, got {args.blur}")
    if not args.noise >= 0:
        raise CanopyStereoError(f"--noise must be >= 0, got {args.noise}")
    if not 1 <= args.samples <= 256:
        raise CanopyStereoError(f"--samples must be 1..256, got {args.samples}")
    if args.placements:
        placements = load_placements(args.placements)
        if placements.unit != rig.world_unit:
            raise CanopyStereoError(f"{args.placements} is in {placements.unit} but the rig in {rig.world_unit}")
        if placements.pairs != list(range(len(placements))):
            raise CanopyStereoError(f"{args.placements}: pairs must be numbered 0..{len(placements) - 1}")
    else:
        placements = calibration_placements(rig)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(rig_path, out / "rig.yaml")
    noise = 0.0 if args.clean else args.noise

    def progress(msg):
        print(msg, flush=True)

    pairs = render_calibration_scene(rig, placements, blur_px=args.blur, noise_sigma=noise, seed=args.seed,
                                     samples=args.samples, progress=progress)
    digits = max(2, len(str(len(pairs) - 1)))
    for p, (left, right) in zip(placements, pairs):
        write_image(out / f"left_{p.pair:0{digits}d}.png", left)
        write_image(out / f"right_{p.pair:0{digits}d}.png", right)
    write_placements(placements, out / "placements.yaml", comment=(
        "Placements of the rendered calibration boards (canopy-stereo simulate calibration);\n"
        f"world frame and unit of {rig_path.name}."))
    print(f"{out}: {len(pairs)} calibration pairs (blur {args.blur:g} px, noise {noise:g} DN) + "
          "placements.yaml + rig.yaml (the true rig)")
    print(f"calibrate with: canopy-stereo calibrate --world-rig {out / 'placements.yaml'} "
          f"\"{out}/left_*.png\" \"{out}/right_*.png\" --pattern {placements.pattern[0]}x{placements.pattern[1]} "
          f"--square {placements.square:g} -o rig.yaml --plot err.png")
    return 0
