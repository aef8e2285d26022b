"""One bag -> one row of traits: the unit of work of ``canopy-stereo batch``.

Each stereo pair of the bag has its right image brought to the left image's
instant first (:class:`~canopy_stereo.skew.SkewCompensator`, as ``rectify_node``
does; ``BatchOptions.skew_compensation``), then goes through the core exactly as
``canopy-stereo reconstruct --measure`` takes a pair:
:func:`~canopy_stereo.pipeline.reconstruct.reconstruct_pair` (the rig's
rectification: Fusiello unless the rig file names Hartley with its homographies; ELAS, triangulation with the rig's
world-frame ``P``), then the
automatic plant mask :func:`~canopy_stereo.segmentation.auto_plant_mask` (the
vegetation index plus the distance of the reconstructed points from the left
camera centre as the depth cue), then
:func:`~canopy_stereo.measure.measure_scene` (canopy extents and volumes, leaves
separated and measured) with the left camera given. The frames' traits are
aggregated by their median; ``frames`` counts the frames measured.

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

#: Trait columns of a row, in order: name -> description (units in the name).
TRAITS = {
    "canopy_height_mm": "canopy extent along the up axis of the measuring frame",
    "canopy_width_mm": "canopy extent across the view",
    "canopy_depth_mm": "canopy extent along the view",
    "hull_volume_cm3": "convex hull volume of the canopy points",
    "voxel_volume_cm3": "volume of the voxels the canopy points occupy",
    "leaf_count": "leaves measured (separated from the plant mask, large enough)",
    "leaf_area_cm2": "summed one-sided area of the measured leaves",
    "mean_leaf_length_mm": "mean leaf length along the surface",
    "mean_leaf_width_mm": "mean leaf width",
    "leaf_area_density_cm-1": "leaf area / hull volume",
    "plant_fraction": "fraction of the left image the plant mask covers",
}


@dataclass(frozen=True)
class BatchOptions:
    """How each bag is processed (picklable; sent with every task).

    Attributes:
        rig: a :class:`~canopy_stereo.io.rig.Rig` used for every bag (overrides
            the rig recorded in the bag), or None to use each bag's own.
        rig_source: how ``rig`` was given (for the ``rig`` column), e.g. its path.
        select: ``{key: {values}}`` metadata filter (see
            :func:`~canopy_stereo.bag.metadata.parse_selection`).
        index: colour cue of the plant mask (``"exg"``, ``"exgr"``, ``"none"``).
        matcher: dense matcher (``"elas"``, ``"sgbm"``).
        max_frames: measure at most this many pairs, evenly spread (0 = all).
        left_topic, right_topic: raw image topics.
        sync_slop_s: largest left/right stamp difference of a pair (s).
        skew_compensation: bring each right image to its left image's instant
            (:class:`~canopy_stereo.skew.SkewCompensator`, as ``rectify_node``).
    """

    rig: object = None
    rig_source: str = ""
    select: dict = field(default_factory=dict)
    index: str = "exg"
    matcher: str = DEFAULT_MATCHER
    max_frames: int = 0
    left_topic: str = "/stereo/left/image_raw"
    right_topic: str = "/stereo/right/image_raw"
    sync_slop_s: float = 0.015
    skew_compensation: bool = True


class Skipped(Exception):
    """The bag is not selected (not an error)."""


def measure_frame(left_bgr, right_bgr, rig, *, index: str = "exg", matcher: str = DEFAULT_MATCHER) -> dict:
    """Traits (see :data:`TRAITS`) of one stereo pair, as ``reconstruct --measure`` with
    the automatic plant mask. Raises :class:`CanopyStereoError` when the pair cannot be
    reconstructed, segmented or measured."""
    from canopy_stereo.geometry.camera import camera_centre
    from canopy_stereo.measure import measure_scene
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair
    from canopy_stereo.segmentation import auto_plant_mask

    rec = reconstruct_pair(left_bgr, right_bgr, rig, matcher=matcher)
    distance = np.linalg.norm(rec.organized - camera_centre(rig.P_left), axis=-1)
    mask = auto_plant_mask(left_bgr, depth=distance, index=index) > 0
    res = measure_scene(rec.organized, mask=mask, ground="auto", unit=rig.world_unit, camera=rig.P_left)
    return traits_of_report(res.report, rig.metres_per_unit * 1000.0, plant_fraction=float(mask.mean()))


def traits_of_report(report: dict, mm_per_unit: float, *, plant_fraction: float = float("nan")) -> dict:
    """The :data:`TRAITS` of a measurement report (REPORT.json dict in world units)."""
    c = report["canopy"]
    leaves = report["leaves"]
    mm, mm2, mm3 = mm_per_unit, mm_per_unit ** 2, mm_per_unit ** 3

    def num(v, scale):
        return float("nan") if v is None else float(v) * scale

    leaf_area_cm2 = sum(lf["area"] for lf in leaves) * mm2 / 100.0
    hull_cm3 = num(c["hull_volume"], mm3 / 1000.0)
    return {
        "canopy_height_mm": num(c["height"], mm),
        "canopy_width_mm": num(c["width"], mm),
        "canopy_depth_mm": num(c["depth"], mm),
        "hull_volume_cm3": hull_cm3,
        "voxel_volume_cm3": num(c["voxel_volume"], mm3 / 1000.0),
        "leaf_count": float(len(leaves)),
        "leaf_area_cm2": leaf_area_cm2,
        "mean_leaf_length_mm": float(np.mean([lf["length"] for lf in leaves])) * mm if leaves else float("nan"),
        "mean_leaf_width_mm": float(np.mean([lf["width"] for lf in leaves])) * mm if leaves else float("nan"),
        "leaf_area_density_cm-1": leaf_area_cm2 / hull_cm3 if hull_cm3 > 0 else float("nan"),
        "plant_fraction": float(plant_fraction),
    }


def aggregate(frames: list[dict]) -> dict:
    """Median of each trait over the frames where it is finite (NaN when none)."""
    out = {}
    for name in TRAITS:
        vals = np.array([f[name] for f in frames], np.float64)
        vals = vals[np.isfinite(vals)]
        out[name] = float(np.median(vals)) if vals.size else float("nan")
    return out


def _iso_utc(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns / 1e9, _dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _spread(n_total: int, n_keep: int) -> set[int]:
    """Indices of ``n_keep`` of ``n_total`` items, evenly spread (all when ``n_keep`` is 0)."""
    if n_keep <= 0 or n_keep >= n_total:
        return set(range(max(n_total, 1)))
    return set(np.unique(np.linspace(0, n_total - 1, n_keep).round().astype(int)).tolist())


def process_bag(path, options: BatchOptions | None = None) -> dict:
    """Measure every stereo pair of the bag at ``path`` and aggregate them into a row.

    Returns ``{"source", "metadata": {...}, "recorded_at", "frames", "frames_failed",
    "rig", "canopy_stereo_version", <TRAITS>}``. Raises :class:`Skipped` when the bag's
    metadata does not match ``options.select``, :class:`CanopyStereoError` (one-line
    message) when it cannot be read (missing, not MCAP, truncated), has no rig, no
    stereo pair, or no frame could be measured.
    """
    from canopy_stereo import __version__
    from canopy_stereo.bag import BagReader
    from canopy_stereo.bag.metadata import RIG_RECORD, canopy_metadata, matches_selection
    from canopy_stereo.batch.frames import image_to_bgr, raw_stereo_pairs, stereo_topics
    from canopy_stereo.skew import SkewCompensator

    options = options or BatchOptions()
    bag = BagReader(path)
    if bag.truncated:
        raise CanopyStereoError(f"truncated bag: {bag.problem}")
    meta, bag_rig = canopy_metadata(bag.metadata(), source=str(path))
    if options.select and not matches_selection(meta, options.select):
        raise Skipped(str(path))
    rig = options.rig if options.rig is not None else bag_rig
    if rig is None:
        raise CanopyStereoError(f"no rig: the bag has no {RIG_RECORD} metadata record; give --rig RIG.yaml")
    rig_source = (options.rig_source or "given") if options.rig is not None else "bag"
    # at most max_frames pairs, spread over the pairs the bag can hold (its smaller stream)
    left_topic, right_topic = stereo_topics(bag, options.left_topic, right_topic=options.right_topic)  # or /compressed
    n_pairs = min((bag.topics[t].message_count if t in bag.topics else 0) for t in (left_topic, right_topic))
    keep = _spread(n_pairs, options.max_frames)
    last = max(keep, default=0)
    measured, failures, first_stamp = [], [], None
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
            measured.append(measure_frame(left_bgr, right_bgr, rig, index=options.index,
                                          matcher=options.matcher))
        except CanopyStereoError as exc:
            failures.append(f"frame {k}: {exc}")
    if first_stamp is None:
        raise CanopyStereoError(f"no stereo pair on {options.left_topic} and {options.right_topic} "
                                f"within {options.sync_slop_s:g} s")
    if not measured:
        raise CanopyStereoError(f"no frame could be measured ({len(failures)} tried; {failures[0]})")
    return {"source": str(path), "metadata": meta, "recorded_at": _iso_utc(first_stamp),
            "frames": len(measured), "frames_failed": len(failures), **aggregate(measured),
            "rig": rig_source, "canopy_stereo_version": __version__}


def one_line(exc: BaseException) -> str:
    """A one-line reason for a failure (the message of a user error, else type: message)."""
    text = str(exc) if isinstance(exc, CanopyStereoError) else f"{type(exc).__name__}: {exc}"
    return " ".join(text.split()) or type(exc).__name__


def run_bag_task(path: str, options: BatchOptions) -> tuple[str, object]:
    """The Dask task: ``("ok", row)``, ``("skipped", None)`` or ``("error", reason)``;
    it never raises for a bad bag (only a dying worker fails the task)."""
    try:
        return "ok", process_bag(path, options)
    except Skipped:
        return "skipped", None
    except MemoryError:
        return "error", "out of memory"
    except Exception as exc:  # noqa: BLE001 - one bad bag must not stop the batch
        return "error", one_line(exc)
