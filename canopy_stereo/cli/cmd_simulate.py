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
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import write_image
from canopy_stereo.io.rig import load_rig

COMMAND = "simulate"
HELP = "render a synthetic plant scene through a rig, with exact ground truth"
DESCRIPTION = __doc__.split("\n\n", 1)[1].strip()


def add_arguments(parser) -> None:
    # scene names are checked by canopy_stereo.sim.build_scene (not imported here: it loads numba)
    parser.add_argument("scene", metavar="SCENE",
                        help="scene name: croton, citrus_branch or seedling_tray")
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


def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_frame(sim, folder: Path) -> None:
    """Write one rendered frame's files into ``folder``."""
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
    rig_path = Path(args.rig) if args.rig else default_rig_path()
    rig = load_rig(rig_path)
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise CanopyStereoError(f"output {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(rig_path, out / "rig.yaml")
    effects = CLEAN if args.clean else None
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
