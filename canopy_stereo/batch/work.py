"""One bag -> one row of traits: the unit of work of ``canopy-stereo batch``.

Each stereo pair of the bag has its right image brought to the left image's
instant first (:class:`~canopy_stereo.skew.SkewCompensator`, as ``rectify_node``
does; ``BatchOptions.skew_compensation``), then goes through the package's one measuring
pipeline, :func:`~canopy_stereo.pipeline.plant.measure_stereo_pair` (as ``reconstruct --measure``,
``demo`` and ``view``: reconstruction, the automatic plant mask, leaves and canopy
measured with the same defaults). The frames' traits are aggregated by their median;
``frames`` counts the frames measured.

Everything here is pure Python over the core (no rclpy): it runs in Dask
workers that read the bag by its path from shared storage.

Units of the row (whatever the rig's world unit): lengths in millimetres,
areas in square centimetres, volumes in cubic centimetres.
"""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field

import numpy as np

from canopy_stereo.disparity import DEFAULT_MATCHER
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.measure.plant import DEFAULT_COLOUR_INDEX, DEFAULT_VOXEL_SIZE_MM

#: Trait columns of a row, in order: name -> description (units in the name).
TRAITS = {
    "canopy_height_mm": "canopy extent along the up axis of the measuring frame",
    "canopy_width_mm": "canopy extent across the view",
    "canopy_depth_mm": "canopy extent along the view",
    "hull_volume_cm3": "convex hull volume of the canopy points",
    "voxel_volume_cm3": "volume of the voxels the canopy points occupy",
    "voxel_size_mm": "voxel edge of voxel_volume_cm3",
    "leaf_count": "leaves measured (separated from the plant mask, large enough)",
    "leaf_area_cm2": "summed one-sided area of the measured leaves",
    "mean_leaf_length_mm": "mean leaf length along the surface",
    "mean_leaf_width_mm": "mean leaf width",
    "leaf_area_density_cm-1": "leaf area / hull volume",
    "plant_fraction": "fraction of the left image the plant covers",
}
#: Text columns of a row beside the traits: the surface the height is measured from.
REFERENCE_COLUMN = "height_reference"
#: ... and why the plant could not be measured in some frames (``frame K: <reason>``, the
#: first such frame; empty when it was measured in every frame it was found in).
ERROR_COLUMN = "plant_error"


@dataclass(frozen=True)
class BatchOptions:
    """How each bag is processed (picklable; sent with every task).

    Attributes:
        rig: a :class:`~canopy_stereo.io.rig.Rig` used for every bag (overrides
            the rig recorded in the bag), or None to use each bag's own, else the
            :data:`RIG_BESIDE` in its folder (:func:`resolve_rig`).
        rig_source: how ``rig`` was given (for the ``rig`` column), e.g. its path.
        select: ``{key: {values}}`` metadata filter (see
            :func:`~canopy_stereo.bag.metadata.parse_selection`).
        index: kept for old callers; the measuring pipeline's plant mask does not use it.
        matcher: dense matcher (``"elas"``, ``"sgbm"``).
        max_frames: measure at most this many pairs, evenly spread (0 = all).
        left_topic, right_topic: raw image topics.
        sync_slop_s: largest left/right stamp difference of a pair (s).
        skew_compensation: bring each right image to its left image's instant
            (:class:`~canopy_stereo.skew.SkewCompensator`, as ``rectify_node``).
        voxel_size_mm: voxel edge of the voxel volume (mm).
        name_pattern: metadata from the file name, e.g. ``"{plant_id}_{date}"``
            (:func:`~canopy_stereo.batch.naming.fields_from_name`); "" = none.
        sidecar: file name -> {key: value} metadata (``--metadata TABLE.csv``,
            :func:`~canopy_stereo.batch.naming.read_sidecar`).
    """

    rig: object = None
    rig_source: str = ""
    select: dict = field(default_factory=dict)
    index: str = DEFAULT_COLOUR_INDEX
    matcher: str = DEFAULT_MATCHER
    voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM
    name_pattern: str = ""
    sidecar: dict = field(default_factory=dict)
    max_frames: int = 0
    left_topic: str = "/stereo/left/image_raw"
    right_topic: str = "/stereo/right/image_raw"
    sync_slop_s: float = 0.015
    skew_compensation: bool = True


class Skipped(Exception):
    """The bag is not selected (not an error)."""


def measure_frame(left_bgr, right_bgr, rig, *, index: str = DEFAULT_COLOUR_INDEX, matcher: str = DEFAULT_MATCHER,
                  voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> dict:
    """Traits (see :data:`TRAITS`) of one stereo pair, all its plants as one canopy: the
    package's one measuring pipeline (:func:`~canopy_stereo.pipeline.plant.measure_stereo_pair`,
    as ``reconstruct --measure``, ``demo`` and ``view``). Raises :class:`CanopyStereoError`
    when the pair cannot be reconstructed, segmented or measured."""
    from canopy_stereo.pipeline.plant import measure_stereo_pair

    _, res = measure_stereo_pair(left_bgr, right_bgr, rig, matcher=matcher, index=index, voxel_size_mm=voxel_size_mm)
    from canopy_stereo.measure.plant import plant_summary

    return plant_traits(plant_summary(res.report), plant_fraction=float(res.mask.mean()))


def measure_frame_plants(left_bgr, right_bgr, rig, *, index: str = DEFAULT_COLOUR_INDEX,
                         matcher: str = DEFAULT_MATCHER, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> dict:
    """``{plant_index: traits}`` of one stereo pair, one entry per plant the measuring
    pipeline finds (``report["plants"]``: 1..N left to right; 0 for a plant measured as the
    scene), with :data:`REFERENCE_COLUMN` and :data:`ERROR_COLUMN` (:func:`plant_traits`; a
    plant that could not be measured is there too, with its reason)."""
    from canopy_stereo.pipeline.plant import measure_stereo_pair

    _, res = measure_stereo_pair(left_bgr, right_bgr, rig, matcher=matcher, index=index, voxel_size_mm=voxel_size_mm)
    out = {}
    for p in res.report["plants"]:
        k = int(p["plant_index"])
        share = float(res.mask.mean()) if res.instances is None or len(res.report["plants"]) == 1 \
            else float(np.mean(res.instances == k))
        out[k] = plant_traits(p, plant_fraction=share)
    return out


def plant_traits(plant: dict, *, plant_fraction: float = float("nan")) -> dict:
    """The :data:`TRAITS` (and :data:`REFERENCE_COLUMN`, :data:`ERROR_COLUMN`) of one entry of
    a measurement report's ``plants`` (:func:`~canopy_stereo.measure.plant.measure_plant`; mm,
    cm^2, cm^3). A plant that could not be measured (its ``error``, see
    :func:`~canopy_stereo.measure.plant.plant_summary`) has every trait but ``plant_fraction``
    NaN (the tables' empty cell), no reference and its reason in :data:`ERROR_COLUMN`."""
    if plant.get("error") is not None:
        return {**{name: float("nan") for name in TRAITS}, "plant_fraction": float(plant_fraction),
                REFERENCE_COLUMN: "", ERROR_COLUMN: str(plant["error"])}
    c = plant["canopy"]

    def num(v):
        return float("nan") if v is None else float(v)

    hull_cm3 = num(c["hull_volume"])
    area = num(plant.get("leaf_area"))
    return {
        "canopy_height_mm": num(c["height"]), "canopy_width_mm": num(c["width"]),
        "canopy_depth_mm": num(c["depth"]), "hull_volume_cm3": hull_cm3,
        "voxel_volume_cm3": num(c["voxel_volume"]), "voxel_size_mm": num(c["voxel_size"]),
        "leaf_count": float(plant.get("n_leaves", 0)), "leaf_area_cm2": area,
        "mean_leaf_length_mm": num(plant.get("mean_leaf_length")),
        "mean_leaf_width_mm": num(plant.get("mean_leaf_width")),
        "leaf_area_density_cm-1": area / hull_cm3 if hull_cm3 > 0 else float("nan"),
        "plant_fraction": float(plant_fraction),
        REFERENCE_COLUMN: (plant.get("reference") or {}).get("kind", ""), ERROR_COLUMN: "",
    }


def aggregate(frames: list[dict]) -> dict:
    """Median of each trait over the frames where it is finite (NaN when none); the
    :data:`REFERENCE_COLUMN` most frames used."""
    out = {}
    for name in TRAITS:
        vals = np.array([f[name] for f in frames], np.float64)
        vals = vals[np.isfinite(vals)]
        out[name] = float(np.median(vals)) if vals.size else float("nan")
    refs = [f.get(REFERENCE_COLUMN, "") for f in frames if f.get(REFERENCE_COLUMN)]
    out[REFERENCE_COLUMN] = max(set(refs), key=refs.count) if refs else ""
    return out


def _iso_utc(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns / 1e9, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _spread(n_total: int, n_keep: int) -> set[int]:
    """Indices of ``n_keep`` of ``n_total`` items, evenly spread (all when ``n_keep`` is 0)."""
    if n_keep <= 0 or n_keep >= n_total:
        return set(range(max(n_total, 1)))
    return set(np.unique(np.linspace(0, n_total - 1, n_keep).round().astype(int)).tolist())


#: A rig file beside the bags (in a bag's folder) that ``batch`` uses when the bag has none.
RIG_BESIDE = "rig.yaml"


def resolve_rig(path, bag_rig, options: BatchOptions):
    """``(rig, source)`` of the bag at ``path``: ``--rig`` (``options.rig``), else the bag's
    own rig record, else :data:`RIG_BESIDE` in the bag's folder; :class:`CanopyStereoError`
    naming all three when none is found."""
    from pathlib import Path

    from canopy_stereo.io.rig import load_rig

    if options.rig is not None:
        return options.rig, options.rig_source or "given"
    if bag_rig is not None:
        return bag_rig, "bag"
    beside = Path(path).parent / RIG_BESIDE
    if beside.is_file():
        return load_rig(beside), str(beside)
    raise CanopyStereoError(f"no rig: the bag has no canopy_stereo_rig metadata record and there is no "
                            f"{RIG_BESIDE} beside it; give --rig RIG.yaml")


def bag_metadata(path, recorded: dict, options: BatchOptions) -> dict:
    """The metadata of the bag at ``path``: its recorded ``canopy_stereo`` keys, updated with
    the fields of its file name (``options.name_pattern``,
    :func:`~canopy_stereo.batch.naming.fields_from_name`) and its row of the sidecar table
    (``options.sidecar``: file name -> {key: value})."""
    from pathlib import Path

    from canopy_stereo.batch.naming import fields_from_name, sidecar_row

    meta = dict(recorded)
    if options.name_pattern:
        meta.update(fields_from_name(Path(path).name, options.name_pattern))
    if options.sidecar:
        meta.update(sidecar_row(options.sidecar, path))
    return meta


def process_bag(path, options: BatchOptions | None = None) -> list[dict]:
    """Measure every stereo pair of the bag at ``path`` and aggregate them into one row per plant.

    Returns rows ``{"source", "plant_index", "metadata": {...}, "recorded_at", "frames",
    "frames_failed", "rig", "canopy_stereo_version", <TRAITS>, height_reference, plant_error}``,
    one per plant the measuring pipeline numbers (1..N left to right; the frames' values of a
    plant aggregated by their median over the frames it was measured in, ``frames``; a frame
    where it could not be measured counts in ``frames_failed`` and the first such frame's
    reason is its ``plant_error``: a plant measured in no frame has a row of empty traits).
    Raises :class:`Skipped` when the bag's metadata does not match ``options.select``,
    :class:`CanopyStereoError` (one-line message) when it cannot be read (missing, not MCAP,
    truncated), has no rig (:func:`resolve_rig`), no stereo pair, or no frame could be measured.
    """
    from canopy_stereo import __version__
    from canopy_stereo.bag import BagReader
    from canopy_stereo.bag.metadata import canopy_metadata, matches_selection
    from canopy_stereo.batch.frames import image_to_bgr, raw_stereo_pairs, stereo_topics
    from canopy_stereo.skew import SkewCompensator

    options = options or BatchOptions()
    bag = BagReader(path)
    if bag.truncated:
        raise CanopyStereoError(f"truncated bag: {bag.problem}")
    recorded, bag_rig = canopy_metadata(bag.metadata(), source=str(path))
    meta = bag_metadata(path, recorded, options)
    if options.select and not matches_selection(meta, options.select):
        raise Skipped(str(path))
    rig, rig_source = resolve_rig(path, bag_rig, options)
    # at most max_frames pairs, spread over the pairs the bag can hold (its smaller stream)
    left_topic, right_topic = stereo_topics(bag, options.left_topic, right_topic=options.right_topic)  # or /compressed
    n_pairs = min((bag.topics[t].message_count if t in bag.topics else 0) for t in (left_topic, right_topic))
    keep = _spread(n_pairs, options.max_frames)
    last = max(keep, default=0)
    per_plant: dict[int, list[dict]] = {}
    plant_failures: dict[int, list[str]] = {}  # plant_index -> "frame K: reason" of the frames it failed in
    n_frames, failures, first_stamp = 0, [], None
    skew = SkewCompensator(enabled=options.skew_compensation)
    for k, (stamp, left, right) in enumerate(raw_stereo_pairs(bag, left_topic, right_topic=right_topic,
                                                              slop_s=options.sync_slop_s)):
        if k > last:
            break  # the frames to measure are done: read no further
        if k + 1 not in keep and k not in keep:
            skew.reset()  # neither this pair nor the next is measured: no need to decode it
            continue
        if k not in keep:  # the previous frame of a measured pair
            skew.observe(image_to_bgr(right), stamp_right_ns=right.stamp_ns)
            continue
        left_bgr, right_bgr, _ = skew.compensate(image_to_bgr(left), image_to_bgr(right),
                                                 stamp_left_ns=left.stamp_ns, stamp_right_ns=right.stamp_ns)
        first_stamp = stamp if first_stamp is None else first_stamp
        try:
            plants = measure_frame_plants(left_bgr, right_bgr, rig, index=options.index,
                                          matcher=options.matcher, voxel_size_mm=options.voxel_size_mm)
        except CanopyStereoError as exc:
            failures.append(f"frame {k}: {exc}")
            continue
        n_frames += 1
        for index, traits in plants.items():
            if traits.get(ERROR_COLUMN):
                plant_failures.setdefault(index, []).append(f"frame {k}: {traits[ERROR_COLUMN]}")
            else:
                per_plant.setdefault(index, []).append(traits)
    if first_stamp is None:
        raise CanopyStereoError(f"no stereo pair on {options.left_topic} and {options.right_topic} "
                                f"within {options.sync_slop_s:g} s")
    if not per_plant:
        why = failures + [f"plant {i} {r}" for i, rs in sorted(plant_failures.items()) for r in rs]
        raise CanopyStereoError(f"no frame could be measured ({len(failures) + n_frames} tried; {why[0]})")
    rows = []
    for index in sorted(set(per_plant) | set(plant_failures)):
        frames = per_plant.get(index, [])
        rows.append({"source": str(path), "plant_index": index, "metadata": meta,
                     "recorded_at": _iso_utc(first_stamp), "frames": len(frames),
                     "frames_failed": len(failures) + n_frames - len(frames), **aggregate(frames),
                     ERROR_COLUMN: (plant_failures.get(index) or [""])[0],
                     "rig": rig_source, "canopy_stereo_version": __version__})
    return rows


def one_line(exc: BaseException) -> str:
    """A one-line reason for a failure (the message of a user error, else type: message)."""
    text = str(exc) if isinstance(exc, CanopyStereoError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split()) or type(exc).__name__


def run_bag_task(path: str, options: BatchOptions) -> tuple[str, object]:
    """The Dask task: ``("ok", rows)`` (one per plant), ``("skipped", None)`` or
    ``("error", reason)``; it never raises for a bad bag (only a dying worker fails the task)."""
    try:
        return "ok", process_bag(path, options)
    except Skipped:
        return "skipped", None
    except MemoryError:
        return "error", "out of memory"
    except Exception as exc:  # noqa: BLE001 - one bad bag must not stop the batch
        return "error", one_line(exc)
