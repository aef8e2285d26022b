"""``canopy-stereo eval-disparity``: error statistics of a disparity map against ground truth."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from canopy_stereo.disparity.metrics import evaluate_disparity
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import read_image
from canopy_stereo.io.middlebury import read_disparity
from canopy_stereo.io.pfm import read_pfm

COMMAND = "eval-disparity"
HELP = "bad>0.5/1/2/4, density and end-point error of a disparity map against ground truth"
DESCRIPTION = """Compare DISP (a PFM; inf or negative = invalid) with GT (a PFM, or an
8/16-bit PNG/PGM whose values are disparity x --gt-scale, 0 = unknown; e.g. 16 for
Tsukuba, 8 for Venus, 4 for Middlebury 2003 quarter size, 3 for 2006 third size).
bad>t counts pixels where both have a value; density is the share of (masked) pixels
with a value; 'bad>2 (all)' also counts pixels without a value as wrong.
--mask: only pixels that are white (255) in MASK count (Middlebury nonocc masks)."""


def add_arguments(p):
    p.add_argument("disp", metavar="DISP.pfm", help="estimated disparity (PFM)")
    p.add_argument("gt", metavar="GT", help="ground-truth disparity (PFM, PNG or PGM)")
    p.add_argument("--mask", metavar="MASK.png", help="evaluate only where the mask is 255")
    p.add_argument("--gt-scale", type=float, default=None, metavar="S",
                   help="integer ground truth: disparity = value / S (needed for PNG/PGM)")
    p.add_argument("--json", action="store_true", help="print the scores as JSON")


def _read_estimate(path: Path) -> np.ndarray:
    if path.suffix.lower() != ".pfm":
        raise CanopyStereoError(f"DISP must be a PFM file, got {path}")
    disp = read_pfm(path)
    if disp.ndim == 3:
        disp = disp[:, :, 0]
    return disp


def run(args) -> int:
    disp = _read_estimate(Path(args.disp))
    gt_path = Path(args.gt)
    if gt_path.suffix.lower() != ".pfm" and args.gt_scale is None:
        raise CanopyStereoError(
            f"{gt_path.name} is an integer image: give --gt-scale "
            "(e.g. 4 for quarter-size Middlebury 2003)")
    gt = read_disparity(gt_path, args.gt_scale)
    mask = None
    if args.mask:
        raw = read_image(args.mask, color=False)
        mask = raw == 255
    if disp.shape != gt.shape:
        raise CanopyStereoError(f"DISP is {disp.shape[1]}x{disp.shape[0]} but GT is "
                                f"{gt.shape[1]}x{gt.shape[0]}")
    scores = evaluate_disparity(disp, gt, mask=mask)
    if args.json:
        print(json.dumps(scores.as_dict(), indent=2))
        return 0
    print(f"evaluated {scores.evaluated} px ({scores.known} with ground truth"
          + (", masked" if mask is not None else "") + ")")
    for t, v in scores.bad.items():
        print(f"bad>{t:g}        {v:7.2f} %")
    print(f"density        {scores.density:7.2f} %")
    print(f"EPE            {scores.epe:7.3f} px")
    print(f"bad>2 (all)    {scores.bad2_all:7.2f} %")
    return 0
