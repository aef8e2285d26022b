"""``canopy-stereo measure``: leaf and canopy sizes of a saved reconstruction."""
from __future__ import annotations

from canopy_stereo.cli.common import check_at_least, check_positive, check_world_unit
from canopy_stereo.errors import CanopyStereoError

COMMAND = "measure"
HELP = "measure leaves and canopy of a reconstruction (ORG.npy or PLY) into REPORT.json"
DESCRIPTION = """Measure a reconstruction saved by 'canopy-stereo reconstruct --organized ORG.npy'
(the H x W x 3 world points of the left image's pixels): per leaf the length along the
surface (tip to base), width across it, one-sided area and plane normal; for the canopy its
height, width and depth in a ground frame (ground plane fitted by RANSAC, or the image's up
direction), convex-hull and voxel volumes, total leaf area and leaf-area density.
Leaves come from --leaf-ids (an id image on the left image, 0 = none; ids are kept) or are
separated automatically inside --mask. A PLY cloud gives the canopy figures only.
Lengths are in the rig's world unit (mm for the paper's rig)."""


def _parse_ground(text: str):
    if text in ("auto", "camera", "view"):
        return text
    parts = text.split(",")
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != 4:
        raise CanopyStereoError(f"--ground must be auto, camera, view or a plane a,b,c,d; got {text!r}")
    import math

    if not all(math.isfinite(v) for v in vals) or not any(vals[:3]):
        raise CanopyStereoError(f"--ground plane a,b,c,d needs finite numbers and a non-zero normal "
                                f"(a,b,c); got {text!r}")
    return vals


def add_arguments(p):
    p.add_argument("cloud", metavar="ORG.npy|CLOUD.ply", help="organized cloud (.npy) or point cloud (.ply)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--leaf-ids", metavar="IDS.png", help="leaf-id image on the left image (0 = not a leaf)")
    which.add_argument("--mask", metavar="MASK.png", help="plant mask on the left image; leaves are separated")
    p.add_argument("--ground", default="auto", metavar="auto|camera|view|a,b,c,d",
                   help="measuring frame: fitted ground plane (auto, default), image up (camera), "
                        "towards the camera (view, for top views) or a plane a x + b y + c z + d = 0")
    p.add_argument("--rig", metavar="RIG.yaml",
                   help="rig of the reconstruction (its left camera and world unit; default: "
                        "the camera is estimated from the cloud)")
    p.add_argument("--unit", default=None, help="world unit when there is no rig (default: PLY comment or mm)")
    p.add_argument("--voxel", type=float, default=None, metavar="SIZE",
                   help="voxel edge for the occupancy volume (world units; default about extent/50)")
    p.add_argument("--model", choices=["auto", "rays", "local", "exact"], default="auto",
                   help="leaf surface model (default auto: rays for reconstructions, exact for "
                        "synthetic clouds)")
    p.add_argument("--min-leaf-pixels", type=int, default=100, help="smaller leaves are skipped")
    p.add_argument("-o", "--output", required=True, metavar="REPORT.json")
    p.add_argument("--csv", metavar="LEAVES.csv", help="also write one row per leaf")
    p.add_argument("--plot", metavar="VIEWS.png", help="also draw top and side views with the dimensions")


def _print_summary(report: dict) -> None:
    """The report's leaves and canopy in the one unit set (mm, cm^2, cm^3)."""
    from canopy_stereo.measure import lab_report

    report = lab_report(report)
    leaves = report["leaves"]
    if leaves:
        print(f"{'leaf':>6} {'length':>9} {'width':>9} {'area':>11}  (mm, mm, cm^2)")
        for lf in leaves:
            flag = "" if lf.get("reliable", True) else "  (unreliable: " + (
                "edge-on" if (lf.get("view_angle_deg") or 0) > 75 else "incomplete") + ")"
            print(f"{lf['id']:>6} {lf['length']:>9.1f} {lf['width']:>9.1f} {lf['area']:>11.2f}{flag}")
    for s in report.get("skipped_leaves", []):
        print(f"skipped leaf {s['id']}: {s['reason']}")
    c = report["canopy"]
    frame = report["frame"]["kind"]
    print(f"canopy ({frame} frame): height {c['height']:.1f} mm, width {c['width']:.1f} mm, "
          f"depth {c['depth']:.1f} mm")
    print(f"hull volume {c['hull_volume']:.6g} cm^3, voxel volume {c['voxel_volume']:.6g} cm^3 "
          f"({c['voxel_size']:g} mm voxels)")
    if c.get("leaf_area") is not None:
        lad = c.get("leaf_area_density")
        print(f"leaf area {c['leaf_area']:.6g} cm^2"
              + (f", leaf-area density {lad:.4g} 1/cm" if lad is not None else ""))


def run(args) -> int:
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.measure import load_cloud, measure_points, measure_scene, plot_views, write_report
    from canopy_stereo.segmentation import read_leaf_ids, read_mask

    ground = _parse_ground(args.ground)
    if args.unit is not None:
        check_world_unit(args.unit)
    if args.voxel is not None:
        check_positive(args.voxel, "--voxel")
    check_at_least(args.min_leaf_pixels, 1, "--min-leaf-pixels")
    cloud, ply_unit = load_cloud(args.cloud)
    rig = load_rig(args.rig) if args.rig else None
    if rig is not None and args.unit is not None and args.unit != rig.world_unit:
        raise CanopyStereoError(f"--unit {args.unit} contradicts the rig's world_unit {rig.world_unit} "
                                "(the rig's unit is used; drop --unit)")
    unit = rig.world_unit if rig is not None else (args.unit or ply_unit or "mm")
    if cloud.ndim == 2:  # PLY points
        if args.leaf_ids or args.mask:
            raise CanopyStereoError("--leaf-ids and --mask need an organized cloud (ORG.npy from "
                                    "'reconstruct --organized'), not a PLY")
        result = measure_points(cloud, ground=ground, unit=unit, voxel_size=args.voxel)
    else:
        ids = read_leaf_ids(args.leaf_ids) if args.leaf_ids else None
        mask = read_mask(args.mask) if args.mask else None
        if rig is not None and tuple(rig.image_size) != (cloud.shape[1], cloud.shape[0]):
            raise CanopyStereoError(f"the cloud is {cloud.shape[1]}x{cloud.shape[0]} but the rig's "
                                    f"images are {rig.image_size[0]}x{rig.image_size[1]}")
        result = measure_scene(cloud, leaf_ids=ids, mask=mask, ground=ground, unit=unit,
                               camera=rig.P_left if rig is not None else "auto",
                               voxel_size=args.voxel, model=args.model,
                               min_leaf_pixels=args.min_leaf_pixels)
    result.report["source"]["file"] = str(args.cloud)
    write_report(result.report, args.output, csv=args.csv)
    _print_summary(result.report)
    print(f"wrote {args.output}" + (f", {args.csv}" if args.csv else ""))
    if args.plot:
        plot_views(result, args.plot, title=str(args.cloud))
        print(f"wrote {args.plot}")
    return 0
