"""``canopy-stereo batch``: many raw stereo bags -> one trait table, on Dask distributed."""
from __future__ import annotations

import sys

COMMAND = "batch"
HELP = "measure every bag of a season into one trait table (Dask: this machine or a cluster)"
DESCRIPTION = """Reconstruct and measure each stereo pair of each bag with the package's one measuring
pipeline (as `reconstruct --measure`, `demo` and `view`: automatic plant mask, canopy
extents and volumes, leaves), aggregate a bag's frames by their median and write
OUT/plants.csv (one row per plant of each bag: source, plant_index 1..N left to right, the
bag's metadata keys, frames, traits with their units in the column names, the height's
reference surface, why a plant could not be measured in a frame (plant_error), package
version), OUT/plants.parquet (with pyarrow), OUT/plots/<plant>.png and OUT/errors.csv. The
rig: --rig, else the bag's own record, else a rig.yaml beside the bag. Metadata: the bag's
record, the file name (--name-pattern) and a table keyed by file name (--metadata). Each
failed bag is printed as one line as it happens. Runs on an embedded Dask LocalCluster of
--workers processes, or on a running cluster (--scheduler). Exit status 1 when any bag
failed, 2 for a usage error, 130 when interrupted (Ctrl-C or SIGTERM: one line, the rows
finished so far kept)."""


def add_arguments(p):
    import os

    from canopy_stereo.disparity import DEFAULT_MATCHER, matcher_names

    p.add_argument("inputs", nargs="+", metavar="INPUT", help="bag (.mcap) or folder of bags (searched recursively)")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output folder")
    p.add_argument("--rig", metavar="RIG.yaml",
                   help="rig file for every bag (default: each bag's own canopy_stereo_rig record, else a "
                        "rig.yaml beside the bag)")
    p.add_argument("--name-pattern", metavar="PATTERN", default="",
                   help="metadata from the file names, e.g. '{plant_id}_{treatment}_{date}' (each {key} one or "
                        "more characters, the rest literal; or a regular expression with (?P<key>...) groups)")
    p.add_argument("--metadata", metavar="TABLE.csv",
                   help="metadata from a table with one row per bag, keyed by file name (column file, filename "
                        "or bag, else the first), the other columns its keys (as PlantCV's metadata files)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, metavar="N",
                   help="worker processes of the embedded LocalCluster, one thread each (default: the "
                        "number of CPUs; ignored with --scheduler)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="address of a running Dask scheduler, e.g. tcp://host:8786 (bags must be on "
                        "storage the workers share, at the same paths)")
    p.add_argument("--resume", action="store_true",
                   help="keep the rows already in OUT/plants.csv and process only the other bags")
    p.add_argument("--select", nargs="+", action="extend", default=[], metavar="KEY=VALUE",
                   help="only bags whose metadata KEY is VALUE (values of one key: any; keys: all)")
    p.add_argument("--index", choices=("exg", "exgr", "none"), default="exg",
                   help="kept for old scripts and ignored: the automatic plant mask finds plants of any colour "
                        "by their shape (segment_plants), the same in every command")
    p.add_argument("--voxel-size", type=float, default=10.0, metavar="MM",
                   help="voxel edge of voxel_volume_cm3, millimetres (default 10; a column of the table)")
    p.add_argument("--matcher", choices=matcher_names(), default=DEFAULT_MATCHER,
                   help=f"dense matcher (default {DEFAULT_MATCHER})")
    p.add_argument("--max-frames", type=int, default=0, metavar="N",
                   help="measure at most N stereo pairs per bag, evenly spread (default 0 = all)")
    p.add_argument("--left-topic", default="/stereo/left/image_raw",
                   help="left raw image topic (default %(default)s)")
    p.add_argument("--right-topic", default="/stereo/right/image_raw",
                   help="right raw image topic (default %(default)s)")
    p.add_argument("--sync-slop", type=float, default=0.015, metavar="S",
                   help="largest left/right stamp difference of a stereo pair, seconds (default 0.015, "
                        "as rectify_node; free-running webcams: half a frame period)")
    p.add_argument("--no-skew-compensation", action="store_true",
                   help="pair the images as they came; by default each right image is brought to its left "
                        "image's instant along the right camera's motion, as rectify_node does")
    p.add_argument("--no-plots", action="store_true", help="do not draw the per-plant plots")
    p.add_argument("--no-progress", action="store_true", help="no progress line even on a terminal")


def run(args) -> int:
    from canopy_stereo.bag.metadata import parse_selection
    from canopy_stereo.batch.engine import run_batch
    from canopy_stereo.batch.work import BatchOptions
    from canopy_stereo.errors import CanopyStereoError

    if args.max_frames < 0:
        raise CanopyStereoError(f"--max-frames must be >= 0, got {args.max_frames}")
    if not args.voxel_size > 0:
        raise CanopyStereoError(f"--voxel-size must be > 0 mm, got {args.voxel_size}")
    if not args.sync_slop >= 0:
        raise CanopyStereoError(f"--sync-slop must be >= 0 s, got {args.sync_slop}")
    rig = None
    if args.rig:
        from canopy_stereo.io.rig import load_rig

        rig = load_rig(args.rig)
    sidecar = {}
    if args.metadata:
        from canopy_stereo.batch.naming import read_sidecar

        sidecar = read_sidecar(args.metadata)
    if args.name_pattern:
        from canopy_stereo.batch.naming import pattern_regex

        pattern_regex(args.name_pattern)  # a bad pattern fails now, in one line
    options = BatchOptions(rig=rig, rig_source=args.rig or "", select=parse_selection(args.select),
                           name_pattern=args.name_pattern, sidecar=sidecar,
                           index=args.index, matcher=args.matcher, max_frames=args.max_frames,
                           voxel_size_mm=args.voxel_size,
                           left_topic=args.left_topic, right_topic=args.right_topic,
                           sync_slop_s=args.sync_slop, skew_compensation=not args.no_skew_compensation)
    _sigterm_interrupts()
    summary = run_batch(args.inputs, args.output, options=options, workers=args.workers,
                        scheduler=args.scheduler, resume=args.resume,
                        progress=False if args.no_progress else None, plots=not args.no_plots)
    print("\n".join(summary.lines()), flush=True)
    if summary.interrupted:
        print("canopy-stereo batch: interrupted", file=sys.stderr)
        return 130
    return 1 if summary.failed else 0


def _sigterm_interrupts() -> None:
    """SIGTERM (a job scheduler's time limit, ``kill``) ends the batch like Ctrl-C: the rows
    finished so far stay on disk and ``--resume`` continues."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        def stop(*_):
            raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, stop)
