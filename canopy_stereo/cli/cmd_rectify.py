"""``canopy-stereo rectify``: rectified pair plus homographies."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from canopy_stereo.cli.common import add_rig_argument
from canopy_stereo.geometry.rectification import StereoRectifier
from canopy_stereo.io.images import check_pair, read_image, write_image
from canopy_stereo.io.rig import load_rig, save_rig
from canopy_stereo.pipeline.reconstruct import RECTIFICATION_METHODS, rectify_rig

COMMAND = "rectify"


def load_match_pairs(globs):
    """Image pairs for pooled Hartley matching from two globs (None -> no pairs)."""
    if not globs:
        return []
    from canopy_stereo.errors import CanopyStereoError
    from canopy_stereo.io.images import expand_image_list

    lefts, rights = expand_image_list(globs[0]), expand_image_list(globs[1])
    if not lefts or len(lefts) != len(rights):
        raise CanopyStereoError(f"--match-pairs: {len(lefts)} left and {len(rights)} right images")
    return [(read_image(a), read_image(b)) for a, b in zip(lefts, rights)]


def rectified_rig(rig, rect):
    """``rig`` with ``rect`` stored in its extra parameters: ``method``, ``H_left``/``H_right``
    and, for Hartley, its suggested ``disp_min``/``disp_max``. A disparity range the rig
    had for another rectification method is dropped (its disparities are not this one's)."""
    from dataclasses import replace

    from canopy_stereo.geometry.rig_rectification import rig_rectification_method

    extra = dict(rig.extra)
    if rig_rectification_method(rig) != rect.method or rect.method == "hartley":
        extra.pop("disp_min", None)
        extra.pop("disp_max", None)
    extra.update(method=rect.method, H_left=[float(v) for v in rect.H_left.ravel()],
                 H_right=[float(v) for v in rect.H_right.ravel()])
    if rect.method == "hartley" and rect.disparity_range is not None:
        extra.update(disp_min=int(rect.disparity_range[0]), disp_max=int(rect.disparity_range[1]))
    return replace(rig, extra=extra)


HELP = "rectify a stereo pair (Fusiello from the rig, or Hartley from matches)"
DESCRIPTION = """Rectify LEFT and RIGHT and write to DIR: left_rect.png, right_rect.png,
homographies.yaml (H_left, H_right: original ideal pixel -> rectified pixel) and
rig_<method>.yaml (the rig with method/H_left/H_right set, and for hartley the suggested
disp_min/disp_max: ready for rectify_node, reconstruct --rig, run and batch, which all
rectify it the same way). Without --method the rig's method is used (else fusiello);
hartley is always estimated here from matches of LEFT/RIGHT (and --match-pairs)."""


def add_arguments(p):
    p.add_argument("left", help="left image")
    p.add_argument("right", help="right image")
    add_rig_argument(p)
    p.add_argument("--method", choices=RECTIFICATION_METHODS, default=None,
                   help="fusiello (calibrated, from the rig's P) or hartley (from matches); "
                        "default: the rig's method, else fusiello")
    p.add_argument("--match-pairs", nargs=2, metavar=("LEFT_GLOB", "RIGHT_GLOB"),
                   help="hartley: pool matches from more pairs taken by the same rig (quote the globs)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")


def run(args) -> int:
    rig = load_rig(args.rig)
    left, right = read_image(args.left), read_image(args.right)
    check_pair(left, right, expected_size=rig.image_size)
    rect = rectify_rig(rig, args.method, left=left, right=right, match_pairs=load_match_pairs(args.match_pairs),
                       from_matches=True)
    method = rect.method
    lr, rr = StereoRectifier(rig, rect).rectify(left, right)
    out = Path(args.output)
    write_image(out / "left_rect.png", lr)
    write_image(out / "right_rect.png", rr)
    H = {"H_left": [float(v) for v in rect.H_left.ravel()],
         "H_right": [float(v) for v in rect.H_right.ravel()]}
    import yaml

    (out / "homographies.yaml").write_text(yaml.safe_dump(H, default_flow_style=None, width=200))
    save_rig(rectified_rig(rig, rect), out / f"rig_{method}.yaml", comment=f"rectification: {method}")
    print(f"method {method}: rectified {rect.size[0]}x{rect.size[1]} written to {out}")
    if rect.method == "fusiello":
        print(f"rectified focal {rect.focal_length:.2f} px, baseline {rect.baseline:.3f} {rig.world_unit}, "
              f"doffs {rect.doffs:.2f} px")
    else:
        print(f"F from {rect.n_inliers} inlier matches; suggested disparity range {rect.disparity_range}")
    print("H_left =\n" + np.array2string(rect.H_left, precision=6))
    print("H_right =\n" + np.array2string(rect.H_right, precision=6))
    return 0
