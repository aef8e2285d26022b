"""``canopy-stereo paper --quick`` (issue 18): the report's numbers are this run's.

One reduced run in a fresh process (as CI and users call it); the test reads the
Markdown report back and checks its numbers against what it can recompute on its
own: the matches files the run wrote, the rendered scenes' exact truth, report.json,
and the PNG files of every figure the report links.
"""
from __future__ import annotations

import json
import re
import time

import cv2
import numpy as np
import pytest

from canopy_stereo.features.result import distribution
from canopy_stereo.features.study import correspondence_correctness, read_matches
from canopy_stereo.sim import render_scene
from canopy_stereo.sim.correspondence import true_right_pixels
from test.conftest import run_cli_subprocess

pytestmark = pytest.mark.slow  # one reduced paper run in a process of its own

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper") / "report"
    t0 = time.monotonic()
    proc = run_cli_subprocess("paper", "-o", out, "--quick", "--methods", "sift,qdmatch",
                              timeout=1200)
    proc.wall_s = time.monotonic() - t0  # the whole run, seconds: an upper bound of every timing
    assert proc.returncode == 0, proc.stderr
    return out, proc, (out / "report.md").read_text(), json.loads((out / "report.json").read_text())


def _md_tables(text: str) -> dict:
    """Markdown tables under each heading: heading -> list of row dicts."""
    tables, heading, lines = {}, None, text.splitlines()
    i = 0
    while i < len(lines):
        ln = lines[i]
        if ln.startswith("#"):
            heading = ln.lstrip("#").strip()
        if ln.startswith("|") and i + 1 < len(lines) and lines[i + 1].startswith("|---"):
            head = [c.strip() for c in ln.strip("|").split("|")]
            rows = []
            i += 2
            while i < len(lines) and lines[i].startswith("|"):
                rows.append(dict(zip(head, [c.strip() for c in lines[i].strip("|").split("|")])))
                i += 1
            tables.setdefault(heading, []).append(rows)
            continue
        i += 1
    return tables


def _num(cell: str) -> float:
    return float(cell.replace("%", "").replace("+", "").strip())


def test_paper_runs_with_progress_and_writes_the_report(paper_run):
    out, proc, md, numbers = paper_run
    assert "report written to" in proc.stdout
    steps = re.findall(r"\[(\d)/(\d)\]", proc.stderr)
    assert [int(a) for a, _ in steps] == list(range(1, 8))
    for section in ("Table 1", "Tables 2-4", "Table 2", "Table 3", "Table 4", "Figure 11",
                    "Figures 15-17", "marked croton leaves"):
        assert section in md
    assert numbers["mode"] == "quick" and numbers["methods"] == ["sift", "qdmatch"]
    # the paper's printed numbers are quoted
    for printed in ("94.46 x 156.24", "87.04 x 144.00", "97.0 x 160.0", "86.0 x 145.0", "31.08 %",
                    "27.25 %", "28.08 %"):
        assert printed in md


def test_leaf_sizes_are_measured_within_tolerance_of_the_rendered_truth(paper_run):
    _, _, md, numbers = paper_run
    sim = render_scene("croton", seed=0)
    truth = {lf["id"]: lf for lf in sim.truth["leaves"] if lf["marked"]}
    (rows,) = _md_tables(md)["Figures 20-22: the two marked croton leaves"]
    assert [int(r["leaf"]) for r in rows] == [1, 2]
    for r in rows:
        lf = truth[int(r["leaf"])]
        tw, tl = (float(x) for x in r["truth W x L (mm)"].split(" x "))
        w, length = (float(x) for x in r["this run W x L (mm)"].split(" x "))
        assert tw == pytest.approx(lf["width"], abs=0.01) and tl == pytest.approx(lf["length"], abs=0.01)
        assert abs(w / lf["width"] - 1) < 0.03 and abs(length / lf["length"] - 1) < 0.03
        # measured, not the truth nor the paper's numbers copied
        assert (w, length) != (tw, tl) and (w, length) not in ((94.46, 156.24), (87.04, 144.0))
        ew, el = (_num(x) for x in r["error W / L"].split("/"))
        assert ew == pytest.approx(100 * (w / tw - 1), abs=0.02)
        assert el == pytest.approx(100 * (length / tl - 1), abs=0.02)
        js = next(e for e in numbers["leaves"]["leaves"] if e["id"] == int(r["leaf"]))
        assert js["width"] == pytest.approx(w, abs=0.006) and js["length"] == pytest.approx(length, abs=0.006)


def test_feature_tables_are_the_matches_the_run_wrote(paper_run):
    out, proc, md, numbers = paper_run
    tables = _md_tables(md)
    headings = {k: v for k, v in tables.items() if k.startswith("Table ") and "paper:" in k}
    assert len(headings) == 3
    sims = {"croton": render_scene("croton", seed=0), "citrus_branch": render_scene("citrus_branch", seed=0)}
    for heading, (rows,) in headings.items():
        scene = next(s for s, info in numbers["features"].items()
                     if heading.startswith(f"Table {info['table']}:"))
        info = numbers["features"][scene]
        size = tuple(info["image_size"])
        assert [r["method"] for r in rows] == ["sift", "qdmatch"]
        corr_col = next(c for c in rows[0] if c.startswith("correct"))
        for r in rows:
            xl, xr = read_matches(out / "matches" / scene / f"{r['method']}.csv")
            assert int(r["num"]) == len(xl) > 0
            assert _num(r["distribution"]) == pytest.approx(100 * distribution(xl, size), abs=0.006)
            if scene in sims:
                share, _ = correspondence_correctness(xl, xr, true_right_pixels(sims[scene]))
                assert _num(r[corr_col]) == pytest.approx(100 * share, abs=0.051)
                assert share >= 0.95
                # leaf cells reached, from the rendered labels (leaf = 1)
                h, w = sims[scene].labels_left.shape
                leaf = (sims[scene].labels_left == 1)[:h // 8 * 8, :w // 8 * 8]
                cells = leaf.reshape(h // 8, 8, w // 8, 8).mean(axis=(1, 3)) > 0.5
                c = np.floor((xl + 0.5) / 8).astype(int)
                c = c[(c[:, 0] < w // 8) & (c[:, 1] < h // 8)]
                used = np.zeros_like(cells)
                used[c[:, 1], c[:, 0]] = True
                assert _num(r["leaf cells reached"]) == pytest.approx(
                    100 * (used & cells).sum() / cells.sum(), abs=0.051)
            else:
                assert "leaf cells reached" not in r
        qd = next(r for r in rows if r["method"] == "qdmatch")
        sift = next(r for r in rows if r["method"] == "sift")
        assert _num(qd["distribution"]) > _num(sift["distribution"])
        assert 0 < _num(qd["propagation (s)"]) < proc.wall_s and sift["propagation (s)"] == "/"


def test_rectification_and_reconstruction_numbers(paper_run):
    _, _, md, numbers = paper_run
    r = numbers["rectification"]
    assert max(abs(a) for a in r["angles_after_deg"]) < 0.01
    assert max(abs(a) for a in r["angles_before_deg"]) > 0.5
    assert r["median_abs_dv_px"] < 0.5
    assert f"median {r['median_abs_dv_px']:.3f} px" in md
    (rows,) = _md_tables(md)["Figures 15-17: rectified pairs and reconstructions"]
    by_title = {row["scene"]: row for row in rows}
    for key in ("croton", "citrus_branch"):
        info = numbers["fig15"].get(key) or numbers["fig17"][key]
        row = by_title[info["title"]]
        assert int(row["points"]) == info["points"] > 10000
        assert float(row["median range error vs truth (mm)"]) == pytest.approx(
            info["median_abs_range_error_mm"], abs=0.006)
        assert info["median_rel_range_error_pct"] < 2.0
    assert by_title[numbers["fig15"]["plants"]["title"]]["median range error vs truth (mm)"] == "no truth"


def test_figures_exist_as_png_with_drawn_pixels(paper_run):
    out, _, md, _ = paper_run
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", md)
    assert len(links) >= 7
    for link in links:
        path = out / link
        assert path.read_bytes()[:8] == PNG_SIGNATURE, link
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] >= 200 and img.shape[1] >= 300, link
        # non-trivial: many distinct colours and real contrast
        assert img.std() > 20, link
        assert len(np.unique(img.reshape(-1, 3)[::7], axis=0)) > 200, link
    # Figure 11 draws coloured lines on the right images: pure red/green/blue pixels exist
    fig11 = cv2.imread(str(out / "figures" / "fig11_epipolar_lines.png"))
    for b, g, r in ((0, 0, 255), (0, 200, 0), (255, 64, 0)):
        assert np.sum(np.all(fig11 == (b, g, r), axis=2)) > 500


def test_table1_is_reported_honestly(paper_run):
    _, _, md, numbers = paper_run
    cal = numbers["calibration"]
    section = md.split("## Table 1", 1)[1].split("## ", 1)[0]
    if cal["available"]:
        (rows,) = _md_tables(md)["Table 1 and Figure 5: calibration in the world frame"]
        for row in rows:
            m, s = cal["table1"][row["axis"]]
            assert float(row["mean absolute error (mm)"]) == pytest.approx(m, abs=6e-4)
        assert float(rows[0]["paper mean (mm)"]) == 0.42
        # the rendered rig is recovered: errors of the paper's size, leave-one-out honest
        assert cal["pairs_used"] == cal["placements"] == 9
        assert max(cal["table1"]["X"][0], cal["table1"]["Y"][0]) < 1.0 and cal["table1"]["Z"][0] < 5.0
        assert cal["rms_left_px"] < 0.2 and cal["rms_right_px"] < 0.2
        assert "fig05_calibration_errors.png" in section
    else:
        assert "Not reproduced in this run" in section and cal["reason"] in section


def test_paper_bad_output_and_methods_fail_with_one_line(tmp_path):
    f = tmp_path / "a_file"
    f.write_text("x")
    proc = run_cli_subprocess("paper", "-o", f, "--quick", "--no-calibration")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [f"canopy-stereo paper: error: {f} exists and is not a folder"]
    proc = run_cli_subprocess("paper", "-o", tmp_path / "x", "--methods", "sift,nope")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert "unknown matching method 'nope'" in proc.stderr


def test_spread_summary_repeats_the_feature_tables(paper_run):
    """Issue 18: the report shows qdmatch's spread per scene next to SIFT's (and ASIFT's
    when it ran), the same numbers as the scene's table."""
    _, _, md, numbers = paper_run
    tables = _md_tables(md)
    (summary,) = tables["Quasi-dense spread per scene"]
    assert [r["scene"] for r in summary] == list(numbers["features"])
    for r in summary:
        rows = {v["method"]: v for v in numbers["features"][r["scene"]]["rows"]}
        for m in ("sift", "qdmatch"):
            assert _num(r[f"{m} distribution"]) == pytest.approx(rows[m]["distribution_pct"], abs=0.006)
            assert int(r[f"{m} num"]) == rows[m]["num"]
        assert _num(r["qdmatch correct"]) == pytest.approx(rows["qdmatch"]["correct_pct"], abs=0.051)
        assert _num(r["qdmatch distribution"]) > _num(r["sift distribution"])
        assert "asift distribution" not in r                      # not run with --methods sift,qdmatch
