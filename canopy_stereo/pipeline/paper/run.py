"""The whole paper run (:func:`run_paper`): every section, the report, ``report.json``."""
from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.pipeline.paper.data import plants_pair, rendered_pair
from canopy_stereo.pipeline.paper.numbers import (
    FULL_METHODS,
    QUICK_METHODS,
)
from canopy_stereo.pipeline.paper.report import format_report
from canopy_stereo.pipeline.paper.sections import (
    section_calibration,
    section_features,
    section_leaves,
    section_reconstruction,
    section_rectification,
)
from canopy_stereo.progress import Progress


def run_paper(out_dir, *, quick: bool = False, seed: int = 0, methods=None,
              progress: Progress | None = None, calibration: bool = True) -> dict:
    """Reproduce the paper on the shipped data; write ``report.md``, ``report.json``,
    ``figures/``, ``tables/``, ``matches/`` and ``clouds/`` under ``out_dir``.

    Args:
        out_dir: output folder (created; files in it are overwritten).
        quick: reduced mode for CI: methods :data:`QUICK_METHODS` and
            :data:`QUICK_PLACEMENTS` calibration placements.
        seed: seed of the rendered scenes (croton, citrus branch, calibration noise).
        methods: feature methods of Tables 2-4 (default :data:`FULL_METHODS`, or
            :data:`QUICK_METHODS` when ``quick``).
        progress: a :class:`~canopy_stereo.progress.Progress` log (``lines=True``; default: silent).
        calibration: run Table 1 / Figure 5.

    Returns:
        The run's numbers (the content of ``report.json``).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise CanopyStereoError(f"{out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    (out / "figures").mkdir(exist_ok=True)
    from canopy_stereo.features.study import parse_methods

    methods = list(methods) if methods is not None else list(QUICK_METHODS if quick else FULL_METHODS)
    methods = parse_methods(",".join(methods))
    progress = progress or Progress(7, lines=True, force=False)
    t_start = time.perf_counter()
    timings = {}
    numbers = {"mode": "quick" if quick else "full", "seed": int(seed), "methods": methods,
               "environment": _environment()}

    progress.step("Table 1 / Figure 5: world-rig calibration on rendered photographs")
    t = time.perf_counter()
    if calibration:
        try:
            numbers["calibration"] = section_calibration(out, quick, seed, progress)
        except CanopyStereoError as exc:
            numbers["calibration"] = {"available": False, "reason": str(exc)}
    else:
        numbers["calibration"] = {"available": False, "reason": "skipped (--no-calibration)"}
    timings["calibration"] = time.perf_counter() - t

    progress.step("loading the shipped pairs (Plants bag, rendering croton and citrus branch)")
    t = time.perf_counter()
    pairs = {"plants": plants_pair(), "croton": rendered_pair("croton", seed),
             "citrus_branch": rendered_pair("citrus_branch", seed)}
    timings["data"] = time.perf_counter() - t

    progress.step("Tables 2-4: feature study")
    t = time.perf_counter()
    numbers["features"] = section_features(out, pairs, methods, progress)
    timings["features"] = time.perf_counter() - t

    progress.step("Figure 11: Hartley rectification, epipolar lines before and after")
    t = time.perf_counter()
    numbers["rectification"] = section_rectification(out, pairs["croton"], progress)
    timings["rectification"] = time.perf_counter() - t

    recon_cache: dict = {}
    progress.step("Figure 15: rectified pairs and reconstructions (croton, Plants)")
    t = time.perf_counter()
    numbers["fig15"] = section_reconstruction(out, pairs, "fig15_rectified_and_3d",
                                              ("croton", "plants"), progress, recon_cache)
    timings["fig15"] = time.perf_counter() - t

    progress.step("Figures 16-17: citrus branch pair and its reconstruction")
    t = time.perf_counter()
    numbers["fig17"] = section_reconstruction(out, pairs, "fig17_citrus_branch_3d",
                                              ("citrus_branch",), progress, recon_cache)
    pair = pairs["citrus_branch"]
    from canopy_stereo.pipeline.figures import panel_row

    fig16 = out / "figures" / "fig16_citrus_branch_pair.png"
    cv2.imwrite(str(fig16), panel_row([pair.left, pair.right], ["original left", "original right"]))
    numbers["fig16"] = {"figure": str(fig16.relative_to(out)), "title": pair.title}
    timings["fig17"] = time.perf_counter() - t

    progress.step("Figures 20-22: the two marked croton leaves")
    t = time.perf_counter()
    numbers["leaves"] = section_leaves(out, pairs["croton"], recon_cache, progress)
    timings["leaves"] = time.perf_counter() - t

    timings["total"] = time.perf_counter() - t_start
    numbers["timings_s"] = timings
    (out / "report.json").write_text(json.dumps(_to_builtin(numbers), indent=1) + "\n")
    (out / "report.md").write_text(format_report(numbers))
    return numbers


def _environment() -> dict:
    import numba

    return {"python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "numba": numba.__version__, "machine": platform.machine(),
            "processor": platform.processor() or platform.machine()}


def _to_builtin(obj):
    if isinstance(obj, dict):
        return {str(k): _to_builtin(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_to_builtin(v) for v in obj]
    if isinstance(obj, (np.floating,)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.ndarray):
        return _to_builtin(obj.tolist())
    return obj
