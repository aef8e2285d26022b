"""``canopy-stereo segment``: plant mask of an image (GrabCut from a rectangle, or automatic)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import read_image

COMMAND = "segment"
HELP = "plant mask of an image: GrabCut from a rectangle, a rough mask, or automatic"
DESCRIPTION = """Separate the plant from the background (the paper's GrabCut step).
--rect x,y,w,h: GrabCut from a rectangle drawn around the plant (everything outside is
background). --seed MASK.png: GrabCut from a rough mask (0/255, or GrabCut labels 0..3).
--auto (the default) with --disparity or --depth: plants, not green things
(segment_plants): the background planes (wall, table, tray) are found in the depth cue,
pots, cans and boxes are smooth, plain solids standing on the ground, plants are what is
rough and textured off the planes, whatever their colour; colour models learned from
those cues decide the rest. Also writes MASK_overlay.png (the mask's outline over the
image, each plant numbered left to right) and prints one line per plant.
--auto without a depth cue, or with --index: vegetation index (ExG on normalised
chromaticity) with Otsu's threshold, plus, with --disparity or --depth, near = plant;
the cues seed GrabCut. For red, yellow or brown plants, or green plants before green
foliage, use --index none with a depth cue, or a rectangle. With --index none, colour models of plant and background
are learned from the pixels the depth cue is sure of; they remove the background gaps
between leaves that the matcher filled with the leaves' disparity (--no-colour-model: the
depth cue alone). The disparity/depth map must be registered to IMAGE (same grid: e.g. a
rectified left image and the D.pfm `canopy-stereo disparity` writes for it, or the
original left image and a reconstruction's organized cloud). Writes an 8-bit PNG,
255 = plant."""


def add_arguments(p):
    p.add_argument("image", help="image to segment (colour)")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--rect", metavar="x,y,w,h", help="rectangle around the plant (pixels)")
    how.add_argument("--seed", metavar="MASK.png", help="rough plant mask or GrabCut labels to refine")
    how.add_argument("--auto", action="store_true", help="automatic plant mask (default)")
    cue = p.add_mutually_exclusive_group()
    cue.add_argument("--disparity", metavar="D.pfm",
                     help="disparity registered to IMAGE (PFM or .npy; high = near; inf/negative = unknown)")
    cue.add_argument("--depth", metavar="Z.npy",
                     help="depth or distance registered to IMAGE (.npy or PFM; NaN = unknown), "
                          "or an organized cloud ORG.npy (distance from its camera is used)")
    p.add_argument("--range", metavar="lo,hi", help="plant range of the disparity/depth cue "
                                                     "(default: automatic, Otsu)")
    p.add_argument("--index", choices=["exg", "exgr", "none"], default=None,
                   help="colour cue of --auto's vegetation-index seeder (default without a depth cue: "
                        "exg; 'none' = no vegetation index: the depth cue, with colour models learned "
                        "from it); with a depth cue and no --index, plants are found by shape instead")
    p.add_argument("--iterations", type=int, default=None,
                   help="GrabCut iterations (default 5, the seeder's; 5 for --rect/--seed too)")
    p.add_argument("--no-refine", action="store_true", help="--auto: skip GrabCut, keep the seed")
    p.add_argument("--no-colour-model", action="store_true",
                   help="--auto --index none: do not learn colour models from the depth cue")
    p.add_argument("-o", "--output", required=True, metavar="MASK.png")


def _load_map(path: str, name: str) -> np.ndarray:
    path_ = Path(path)
    if not path_.is_file():
        raise CanopyStereoError(f"{name} file not found: {path_}")
    if path_.suffix.lower() == ".npy":
        try:
            arr = np.load(path_, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise CanopyStereoError(f"{path_} is not a readable .npy array: {exc}") from None
    else:
        from canopy_stereo.io.pfm import read_pfm

        arr = read_pfm(path_)
    arr = np.asarray(arr, np.float64)
    if arr.ndim == 3 and arr.shape[2] == 3 and name == "depth":
        from canopy_stereo.geometry.camera import camera_centre
        from canopy_stereo.measure.viewpoint import estimate_camera

        P = estimate_camera(arr)
        if P is None:
            raise CanopyStereoError(f"{path_}: cannot tell the camera of this organized cloud; "
                                    "pass a depth map instead")
        return np.linalg.norm(arr - camera_centre(P), axis=-1)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise CanopyStereoError(f"{path_}: {name} map must be (H, W), got shape {arr.shape}")
    return arr


def _parse_range(text):
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise CanopyStereoError(f"--range must be lo,hi (two numbers), got {text!r}") from None
    return lo, hi


def run(args) -> int:
    from canopy_stereo.segmentation import IMAGE_SEEDER, grabcut_mask, grabcut_rect, parse_rect, plant_mask, write_mask

    # the defaults are the one seeder's CLI preset (IMAGE_SEEDER)
    index = IMAGE_SEEDER.colour_cue if args.index is None else args.index
    iterations = IMAGE_SEEDER.iterations if args.iterations is None else args.iterations
    image = read_image(args.image)
    if args.rect:
        if args.disparity or args.depth:
            raise CanopyStereoError("--disparity/--depth are cues of --auto, not of --rect")
        mask = grabcut_rect(image, parse_rect(args.rect), iterations=iterations)
        how = f"GrabCut from rectangle {args.rect}"
    elif args.seed:
        seed = read_image(args.seed, color=False)
        mask = grabcut_mask(image, seed, iterations=iterations)
        how = f"GrabCut from {args.seed}"
    elif (args.disparity or args.depth) and args.index is None and args.range is None:
        return _segment_plants(args, image)
    else:
        disparity = _load_map(args.disparity, "disparity") if args.disparity else None
        depth = _load_map(args.depth, "depth") if args.depth else None
        rng = _parse_range(args.range)
        if rng is not None and disparity is None and depth is None:
            raise CanopyStereoError("--range needs --disparity or --depth")
        settings = IMAGE_SEEDER.replace(colour_cue=index,
                                        disparity_range=rng if disparity is not None else None,
                                        depth_range=rng if depth is not None else None,
                                        iterations=iterations, refine=not args.no_refine,
                                        colour_model=False if args.no_colour_model else None)
        mask = plant_mask(image, settings, disparity=disparity, depth=depth)
        cues = [f"index {index}"] if index != "none" else []
        if disparity is not None or depth is not None:
            cues.append("disparity" if disparity is not None else "depth")
            if index == "none" and not args.no_colour_model:
                cues.append("learned colour")
        how = "automatic (" + ", ".join(cues) + ")"
    write_mask(args.output, mask)
    n = int(np.count_nonzero(mask))
    print(f"{how}: {100.0 * n / mask.size:.1f} % plant ({n} of {mask.size} pixels)")
    print(f"wrote {args.output}")
    return 0


def _segment_plants(args, image) -> int:
    """``--auto`` with a depth cue: :func:`~canopy_stereo.segmentation.segment_plants`."""
    from canopy_stereo.io.images import write_image
    from canopy_stereo.segmentation import mask_overlay, segment_plants, write_mask

    disparity = _load_map(args.disparity, "disparity") if args.disparity else None
    depth = _load_map(args.depth, "depth") if args.depth else None
    seg = segment_plants(image, disparity=disparity, depth=depth)
    write_mask(args.output, seg.mask)
    out = Path(args.output)
    overlay = out.with_name(out.stem + "_overlay.png")
    write_image(overlay, mask_overlay(image, seg.mask, instances=seg.instances))
    n = int(np.count_nonzero(seg.mask))
    cue = "disparity" if disparity is not None else "depth"
    print(f"automatic (plants by shape, {cue}, learned colour): {100.0 * n / seg.mask.size:.1f} % plant "
          f"({n} of {seg.mask.size} pixels), {seg.n_plants} plant(s)")
    for p in seg.plants:
        x, y, w, h = p["bbox"]
        print(f"plant {p['plant_index']}: {p['pixels']} pixels, box x {x}..{x + w - 1}, y {y}..{y + h - 1}")
    print(f"wrote {args.output} and {overlay}")
    return 0
