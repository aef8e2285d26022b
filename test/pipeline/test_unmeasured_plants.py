"""A plant that cannot be measured does not take the frame down: the simulated seedling tray
(320x240, automatic instances) has seedlings in the band along the left image border that the
right camera does not see, so their pixels get no 3D point. The one measuring pipeline reports them with
their reason and measures the others; the CLI's summary, REPORT.json and the batch's rows
and tables say which plants were not measured."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from canopy_stereo.measure.plants import REFERENCE_KINDS
from canopy_stereo.sim import render_scene, rig_at_resolution

pytestmark = pytest.mark.slow  # ELAS + the automatic mask + ~30 seedlings measured: ~5 s


@pytest.fixture(scope="module")
def tray(paper_rig):
    return render_scene("seedling_tray", rig_at_resolution(paper_rig, 0.5))


@pytest.fixture(scope="module")
def measured(tray):
    from canopy_stereo.pipeline.plant import measure_stereo_pair

    return measure_stereo_pair(tray.left, tray.right, tray.rig)[1]


def _has_points(measured, k: int) -> bool:
    pts = measured.organized_mm[measured.instances == k]
    return bool(np.all(np.isfinite(pts), axis=1).any())


def test_the_plants_without_points_are_reported_and_the_others_measured(measured, tmp_path):
    from canopy_stereo.measure import write_report
    from canopy_stereo.measure.plant import measurement_lines

    report = measured.report
    plants = report["plants"]
    assert [p["plant_index"] for p in plants] == list(range(1, int(measured.instances.max()) + 1))
    failed = [p for p in plants if p["error"] is not None]
    ok = [p for p in plants if p["error"] is None]
    # the truth of the reason: the failed plants are those whose pixels have no 3D point
    assert failed and len(ok) > 20
    assert [p["plant_index"] for p in failed] == [p["plant_index"] for p in plants
                                                 if not _has_points(measured, p["plant_index"])]
    for p in failed:
        assert "0 valid 3D points" in p["error"] and "\n" not in p["error"]
        # in the band along the left border that the right camera does not see (no disparity)
        cols = np.nonzero((measured.instances == p["plant_index"]).any(axis=0))[0]
        assert cols.max() < np.nonzero(np.isfinite(measured.organized_mm[..., 2]).any(axis=0))[0].min()
        assert p["canopy"] is None and p["reference"] is None and p["n_leaves"] is None
        assert p["leaf_area"] is None and p["mean_leaf_length"] is None
    for p in ok:  # measured as before
        assert p["reference"]["kind"] in REFERENCE_KINDS
        assert 0 < p["canopy"]["height"] < 200 and p["canopy"]["hull_volume"] > 0
    assert report["n_plants"] == len(plants) and report["n_plants_not_measured"] == len(failed)
    # the printed summary: the count on its first line, one line per plant not measured
    lines = measurement_lines(report)
    assert f"({len(plants)} plants, {len(failed)} not measured)" in lines[0]
    for p in failed:
        assert sum(line.startswith(f"  plant {p['plant_index']}: not measured: ") for line in lines) == 1
    # REPORT.json: the missing figures are null, the reason is there
    path = write_report(report, tmp_path / "REPORT.json")
    written = json.loads(path.read_text())
    assert written["n_plants_not_measured"] == len(failed)
    got = {p["plant_index"]: p for p in written["plants"]}
    for p in failed:
        assert got[p["plant_index"]]["canopy"] is None and got[p["plant_index"]]["error"] == p["error"]


def test_batch_rows_name_the_plants_not_measured(tray, measured, tmp_path):
    """The batch (its bag read, its one pipeline, its rows and plants.csv) on a one-pair bag of the tray."""
    from canopy_stereo.batch.table import ResultTable
    from canopy_stereo.batch.work import ERROR_COLUMN, TRAITS, process_bag
    from canopy_stereo.ros.bundled import write_stereo_bag

    bag = write_stereo_bag(tmp_path / "tray.mcap", [(tray.left, tray.right, 10**18, 10**18)], rig=tray.rig)
    rows = {r["plant_index"]: r for r in process_bag(bag)}
    want = {p["plant_index"]: p for p in measured.report["plants"]}
    assert sorted(rows) == sorted(want)  # the same plants as the one pipeline, failed ones included
    for k, r in rows.items():
        if want[k]["error"] is None:
            assert r["frames"] == 1 and r["frames_failed"] == 0 and r[ERROR_COLUMN] == ""
            assert r["canopy_height_mm"] == pytest.approx(want[k]["canopy"]["height"], rel=1e-9)
            assert r["height_reference"] == want[k]["reference"]["kind"]
        else:
            assert r["frames"] == 0 and r["frames_failed"] == 1
            assert r[ERROR_COLUMN] == f"frame 0: {want[k]['error']}"
            assert all(np.isnan(r[name]) for name in TRAITS) and r["height_reference"] == ""
    table = ResultTable(tmp_path / "out")
    table.add_rows(list(rows.values()))
    with open(tmp_path / "out" / "plants.csv", newline="") as f:
        cells = {int(c["plant_index"]): c for c in csv.DictReader(f)}
    for k, c in cells.items():
        failed = want[k]["error"] is not None
        assert (c["canopy_height_mm"] == "") == failed and (c[ERROR_COLUMN] != "") == failed


def test_reconstruct_measure_exits_0_and_names_each_plant_not_measured(tray, measured, tmp_path, cli):
    from canopy_stereo.io.images import write_image
    from canopy_stereo.io.rig import save_rig

    write_image(tmp_path / "l.png", tray.left)
    write_image(tmp_path / "r.png", tray.right)
    rig = save_rig(tray.rig, tmp_path / "rig.yaml")
    code, out, err = cli("reconstruct", tmp_path / "l.png", tmp_path / "r.png", "--rig", rig,
                         "-o", tmp_path / "c.ply", "--measure", "--report", tmp_path / "REPORT.json")
    assert code == 0, err
    failed = [p for p in measured.report["plants"] if p["error"] is not None]
    assert f"{len(failed)} not measured)" in out
    for p in failed:
        assert out.count(f"plant {p['plant_index']}: not measured: {p['error']}\n") == 1
    written = json.loads((tmp_path / "REPORT.json").read_text())
    assert written["n_plants_not_measured"] == len(failed)
