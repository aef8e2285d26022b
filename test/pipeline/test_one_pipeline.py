"""One measuring pipeline: ``demo``, ``reconstruct --measure --auto-mask``, ``batch`` and ``view``
report identical measurements for each bundled bag (issue 23, item 1).

The four commands run as a user runs them (each its own process, at once: the machine's two
cores share them), on the bag's first stereo pair: ``demo`` and ``view`` through the ROS 2
graph (rectify, ELAS disparity, ...), ``reconstruct`` on the pair's two images, ``batch`` on
the bag with ``--max-frames 1`` (the first pair) on a Dask LocalCluster. The summaries print
the same lines (:func:`canopy_stereo.measure.plant.measurement_lines`: mm, cm^2, cm^3), and
the batch table's numbers are the report's to the last digit written.
"""
from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _first_pair(scene: str, out):
    import cv2

    from canopy_stereo.bag import BagReader
    from canopy_stereo.batch.frames import image_to_bgr, raw_stereo_pairs
    from canopy_stereo.ros.bundled import LEFT_TOPIC, RIGHT_TOPIC, bundled_bag

    _, left, right = next(iter(raw_stereo_pairs(BagReader(bundled_bag(scene)), LEFT_TOPIC,
                                                 right_topic=RIGHT_TOPIC, slop_s=0.015)))
    paths = out / "left.png", out / "right.png"
    for path, img in zip(paths, (left, right)):
        assert cv2.imwrite(str(path), image_to_bgr(img))
    return paths


def _measurement_block(text: str) -> list[str]:
    """The measurement lines of a command's output (from 'measured:' to the last leaf line)."""
    lines = [ln.strip() for ln in text.splitlines()]
    start = next(i for i, ln in enumerate(lines) if ln.startswith("measured: "))
    block = []
    for ln in lines[start:]:
        if not ln.startswith(("measured:", "canopy:", "volumes:", "plant ", "leaf ", "...")):
            break
        block.append(ln)
    return block


@pytest.mark.parametrize("scene", ["croton", "plants"])
def test_every_entry_point_reports_the_same_measurements(scene, tmp_path):
    pytest.importorskip("rclpy")
    pytest.importorskip("distributed")
    pytest.importorskip("rerun")
    from canopy_stereo.ros.bundled import bundled_bag, bundled_rig

    left, right = _first_pair(scene, tmp_path)
    bag, rig = bundled_bag(scene), bundled_rig(scene)
    cmd = [sys.executable, "-m", "canopy_stereo.cli"]
    runs = {
        "demo": cmd + ["demo", "--scene", scene, "--out", str(tmp_path / "demo")],
        "view": cmd + ["view", str(bag), "--save", str(tmp_path / "v.rrd")],  # the rig: the bag's
        "reconstruct": cmd + ["reconstruct", str(left), str(right), "--rig", str(rig), "-o", str(tmp_path / "r.ply"),
                              "--measure", "--auto-mask", "--report", str(tmp_path / "r.json")],
        # no --rig: the bundled bags carry their rig (item 7)
        "batch": cmd + ["batch", str(bag), "-o", str(tmp_path / "b"), "--max-frames", "1",
                        "--workers", "1", "--no-plots", "--no-progress"],
    }
    procs = {k: subprocess.Popen(v, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
             for k, v in runs.items()}
    out = {}
    for name, p in procs.items():
        stdout, stderr = p.communicate(timeout=900)
        assert p.returncode == 0, f"{name}: {stderr[-2000:]}"
        out[name] = stdout
    demo = _measurement_block((tmp_path / "demo" / f"{scene}_summary.txt").read_text())
    # the same lines, leaf by leaf, from each entry point that prints them
    assert len(demo) >= 4 and demo[0].startswith("measured: the automatic plant mask")
    assert not any(ln.startswith(("plant mask", "plant cloud")) for ln in demo)
    assert _measurement_block(out["view"]) == demo
    assert _measurement_block(out["reconstruct"])[:len(demo) - 1] == demo[:-1]  # it lists every leaf
    # the batch table, one row per plant: the report's numbers (rounded as the table writes them)
    report = json.loads((tmp_path / "r.json").read_text())
    with open(tmp_path / "b" / "plants.csv", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["plant_index"]) for r in rows] == [p["plant_index"] for p in report["plants"]]
    for row, plant in zip(rows, report["plants"]):
        c = plant["canopy"]
        expected = {"canopy_height_mm": c["height"], "canopy_width_mm": c["width"], "canopy_depth_mm": c["depth"],
                    "hull_volume_cm3": c["hull_volume"], "voxel_volume_cm3": c["voxel_volume"],
                    "voxel_size_mm": c["voxel_size"], "leaf_count": plant["n_leaves"],
                    "leaf_area_cm2": plant["leaf_area"]}
        for column, value in expected.items():
            assert float(row[column]) == pytest.approx(value, rel=1e-5, abs=1e-6), column
        assert row["rig"] == "bag" and row["height_reference"] == (plant["reference"] or {}).get("kind", "")
    assert report["units"] == {"length": "mm", "area": "cm^2", "volume": "cm^3", "leaf_area_density": "1/cm"}
    c = report["canopy"]
    assert report["source"]["mask"] == "automatic" and c["voxel_size"] == 10.0
    assert np.isfinite(c["height"]) and c["height"] > 100 and len(report["leaves"]) >= 5
    assert (tmp_path / "r_overlay.png").is_file() and (tmp_path / "demo" / f"{scene}_overlay.png").is_file()
