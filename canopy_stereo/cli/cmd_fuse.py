"""``canopy-stereo fuse``: several views -> one fused, 360-degree PLY model."""
from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np

from canopy_stereo.disparity import matcher_names
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.rig import UNIT_TO_METRES, unit_to_metres
from canopy_stereo.pipeline.reconstruct import RECTIFICATION_METHODS

COMMAND = "fuse"
HELP = "fuse stereo views (or PLY clouds) from several viewpoints into one model"
DESCRIPTION = """Merge views of one plant into a single cloud. A view is a folder with left.png,
right.png and rig.yaml (optional mask.png, pose.yaml), reconstructed here, or with cloud.ply
(optional pose.yaml, rig.yaml). Poses (rig frame -> world, 4x4) come from --poses (poses.yaml:
'unit' and 'poses: {view folder name: 16 numbers row-major}', or a 'turntable' section with
angles), from each view's pose.yaml, or, when no view has one, from registration: feature
matches between the views' left images lifted to 3-D, robust point-to-plane ICP between
consecutive views and a pose-graph loop closure when the views go all the way round (the world
frame is then the first view's rig frame). The views are merged on a voxel grid that averages
overlapping points, keeps colours and per-point view counts (PLY property 'views') and drops
single-view points that another view sees through. Prints the registration residuals.

A robot's recording instead (--bag REC.mcap --fixed-frame base_link): its clouds (the one
.../points2 topic, or --cloud-topic) are placed by the recording's own /tf and /tf_static,
each at its stamp, interpolated, as fusion_node does live; a cloud without a transform is
skipped with tf's reason."""


def parse_length(text: str, unit: str, *, name: str = "length") -> float:
    """``"2mm"``, ``"0.002 m"`` or ``"2"`` (already in ``unit``) -> a length in ``unit``."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*([a-zA-Z]*)\s*", str(text))
    if not m:
        raise CanopyStereoError(f"{name} must be a number with an optional unit (e.g. 2mm), got {text!r}")
    value, given = float(m.group(1)), m.group(2)
    if given and given not in UNIT_TO_METRES:
        raise CanopyStereoError(f"{name}: unknown unit {given!r}; use one of {', '.join(UNIT_TO_METRES)}")
    if value <= 0:
        raise CanopyStereoError(f"{name} must be positive, got {text!r}")
    return value * unit_to_metres(given) / unit_to_metres(unit) if given else value


def add_arguments(p):
    p.add_argument("views", nargs="*", metavar="VIEW_DIR", help="view folders, in capture order")
    p.add_argument("--bag", metavar="REC.mcap",
                   help="fuse a recording's clouds placed by its /tf + /tf_static (with --fixed-frame)")
    p.add_argument("--fixed-frame", metavar="FRAME", help="with --bag: the frame to fuse in, e.g. base_link")
    p.add_argument("--cloud-topic", metavar="TOPIC", help="with --bag: the PointCloud2 topic (default: the "
                   "recording's one .../points2)")
    p.add_argument("-o", "--output", required=True, metavar="fused.ply")
    p.add_argument("--poses", metavar="poses.yaml", help="rig poses of the views (see above)")
    p.add_argument("--voxel", default="2mm", help="fusion voxel, e.g. 2mm (default 2mm)")
    p.add_argument("--reg-voxel", default=None,
                   help="registration (ICP) voxel, about the depth noise (default 1.5 x --voxel)")
    p.add_argument("--unit", default=None, choices=sorted(UNIT_TO_METRES),
                   help="unit of cloud.ply files that name none")
    p.add_argument("--loop", choices=("auto", "yes", "no"), default="auto",
                   help="close the loop last -> first view when registering (default: when it registers)")
    p.add_argument("--min-overlap", type=float, default=0.5,
                   help="least share of a view near its neighbour after registration (default 0.5)")
    p.add_argument("--min-views", type=int, default=1, help="keep points seen by at least N views")
    p.add_argument("--no-free-space", action="store_true", help="keep single-view points others see through")
    p.add_argument("--method", choices=RECTIFICATION_METHODS, default=None,
                   help="rectification of stereo-pair views (default: each rig's method, else fusiello)")
    p.add_argument("--matcher", choices=matcher_names(), default="sgbm")
    p.add_argument("--poses-out", metavar="POSES.yaml", help="write the poses used (e.g. registered ones)")


def _resolve_poses(views, args, unit):
    from canopy_stereo.fusion.errors import UnitMismatchError
    from canopy_stereo.fusion.poses import read_poses

    given = {}
    if args.poses:
        ps = read_poses(args.poses)
        if ps.unit != unit:
            raise UnitMismatchError(f"{args.poses} is in {ps.unit} but the views are in {unit}")
        names = [v.name for v in views]
        unknown = sorted(set(ps.poses) - set(names) - {""})
        if unknown:
            raise CanopyStereoError(f"{args.poses} names view(s) {', '.join(unknown)} that were not given "
                                    f"(views: {', '.join(names)})")
        given = ps.poses
    poses = [given.get(v.name, v.pose) for v in views]
    have = [v.name for v, T in zip(views, poses) if T is not None]
    if have and len(have) < len(views):
        missing = [v.name for v, T in zip(views, poses) if T is None]
        raise CanopyStereoError(f"view(s) {', '.join(missing)} have no pose while {', '.join(have)} do: "
                                "give every view a pose, or none to register them all")
    return poses if have else None


def run_bag(args) -> int:
    """``fuse --bag``: the recording's clouds placed by its TF, fused on the voxel grid."""
    from canopy_stereo.fusion.incremental import IncrementalFusion
    from canopy_stereo.fusion.plyout import write_fused_ply
    from canopy_stereo.fusion.poses import write_poses
    from canopy_stereo.ros.bag_fusion import posed_clouds

    if args.views or args.poses:
        raise CanopyStereoError("--bag fuses a recording by its TF: give no view folders nor --poses")
    if not args.fixed_frame:
        raise CanopyStereoError("--bag needs --fixed-frame (the frame to fuse in, e.g. base_link)")
    t0 = time.perf_counter()
    got = posed_clouds(args.bag, fixed_frame=args.fixed_frame.lstrip("/"), cloud_topic=args.cloud_topic)
    print(f"{args.bag}: {len(got.clouds) + len(got.skipped)} clouds on {got.topic} "
          f"(frame {', '.join(sorted(got.frames)) or '-'}), {len(got.clouds)} placed by TF in {args.fixed_frame}")
    for line in got.skipped:
        print(f"  skipped {line}")
    if not got.clouds:
        raise CanopyStereoError(f"no cloud of {args.bag} has a transform to {args.fixed_frame}")
    voxel = parse_length(args.voxel, "m", name="--voxel")
    fusion = IncrementalFusion(voxel, unit="m", free_space=not args.no_free_space, min_views=args.min_views)
    for _, points, colours, T in got.clouds:
        fusion.add(points, colours, pose=T)
    fused = fusion.fused()
    write_fused_ply(args.output, fused, comments=[f"canopy-stereo fuse --bag {args.bag} in {args.fixed_frame}"])
    if args.poses_out:
        write_poses(args.poses_out, {f"cloud_{stamp}": T for stamp, _, _, T in got.clouds}, "m",
                    comment=f"cloud poses ({got.topic} frame -> {args.fixed_frame}) looked up in the bag's TF")
    print(f"fused: {len(fused)} points (voxel {voxel * 1000:g} mm) in {time.perf_counter() - t0:.1f} s; "
          f"wrote {args.output}" + (f" and {args.poses_out}" if args.poses_out else ""))
    return 0


def run(args) -> int:
    if args.bag:
        return run_bag(args)
    if not args.views:
        raise CanopyStereoError("give view folders (or --bag REC.mcap --fixed-frame FRAME)")
    from canopy_stereo.fusion.fuse import fuse_views
    from canopy_stereo.fusion.plyout import write_fused_ply
    from canopy_stereo.fusion.poses import write_poses
    from canopy_stereo.fusion.registration import RegistrationSettings, check_given_poses, register_views
    from canopy_stereo.fusion.views import common_unit
    from canopy_stereo.pipeline.views import load_view

    t0 = time.perf_counter()
    folders = [Path(v) for v in args.views]
    names = [f.resolve().name for f in folders]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise CanopyStereoError(f"view folder names must differ (they name the poses): {', '.join(dupes)}")
    from canopy_stereo.cli.progress import warm_up_kernels
    from canopy_stereo.progress import Progress

    if any(not (f / "cloud.ply").is_file() for f in folders):
        warm_up_kernels()  # views given as image pairs are reconstructed with ELAS
    views = []
    bar = Progress(len(folders), "loading view")
    for f in folders:
        t = time.perf_counter()
        bar.step(f.name)
        view = load_view(f, unit=args.unit, method=args.method, matcher=args.matcher)
        views.append(view)
        bar.close()
        print(f"view {view.name}: {len(view.points)} points ({view.unit})"
              f"{', pose from pose.yaml' if view.pose is not None else ''}  [{(time.perf_counter() - t):.1f} s]")
    unit = common_unit(views)
    voxel = parse_length(args.voxel, unit, name="--voxel")
    reg_voxel = parse_length(args.reg_voxel, unit, name="--reg-voxel") if args.reg_voxel else 1.5 * voxel
    settings = RegistrationSettings(voxel=reg_voxel, min_overlap=args.min_overlap)
    poses = _resolve_poses(views, args, unit)
    t = time.perf_counter()
    if poses is None:
        if len(views) < 2:
            raise CanopyStereoError("one view without a pose: nothing to register or fuse")
        loop = {"auto": "auto", "yes": True, "no": False}[args.loop]
        reg = register_views(views, settings, loop=loop)
        poses = reg.poses
        print(f"registration (world = rig frame of {views[0].name}), residuals in {unit}:")
        for pr, (dt, dr) in zip(reg.pairs, reg.residuals_after):
            f = pr.features
            how = (f"features {f.inliers}/{f.matches} consistent, {pr.candidates} candidate(s)"
                   if f is not None else pr.initial)
            print(f"  {views[pr.target].name} <- {views[pr.source].name}: ICP rmse {pr.icp.rmse:.3f}, "
                  f"overlap {pr.icp.overlap:.0%}, {pr.icp.iterations} iterations ({how}); "
                  f"graph residual {dt:.3f} {unit} / {dr:.3f} deg")
        if reg.loop_closed:
            dt, dr = reg.residuals_before[-1]
            print(f"  loop closed: chain disagreed with the closing edge by {dt:.3f} {unit} / {dr:.3f} deg "
                  "before the pose-graph optimisation")
        for note in reg.notes:
            print(f"  {note}")
    else:
        print(f"poses given; residuals of neighbouring views in {unit}:")
        for pc in check_given_poses(views, poses, settings=settings):
            print(f"  {views[pc.target].name} <- {views[pc.source].name}: rmse {pc.rmse:.3f}, "
                  f"overlap {pc.overlap:.0%} within {pc.radius:g}")
    t_reg = time.perf_counter() - t
    t = time.perf_counter()
    fused = fuse_views(views, poses, voxel=voxel, free_space=not args.no_free_space, min_views=args.min_views)
    t_fuse = time.perf_counter() - t
    write_fused_ply(args.output, fused, comments=[f"canopy-stereo fuse of {len(views)} views: "
                                                  + " ".join(v.name for v in views)])
    if args.poses_out:
        write_poses(args.poses_out, {v.name: T for v, T in zip(views, poses)}, unit,
                    comment="rig poses (rig frame -> world) used by canopy-stereo fuse")
    hist = np.bincount(fused.view_count, minlength=len(views) + 1)[1:]
    print(f"fused: {len(fused)} points from {fused.stats['input_points']} (voxel {voxel:g} {unit}); "
          f"{fused.removed_free_space} single-view voxels removed as seen-through")
    print("points seen by 1.." + str(len(views)) + " views: " + " ".join(str(int(h)) for h in hist))
    print(f"time: registration {t_reg:.1f} s, fusion {t_fuse:.1f} s, total {time.perf_counter() - t0:.1f} s")
    print(f"wrote {args.output}" + (f" and {args.poses_out}" if args.poses_out else ""))
    return 0
