"""``canopy-stereo features``: the study table, its files and its error messages."""
from __future__ import annotations

import csv
import time

import cv2
import numpy as np
import pytest

from canopy_stereo.features.study import read_matches
from canopy_stereo.io.pfm import write_pfm
from canopy_stereo.sim.stereo_pair import slanted_plane_pair


@pytest.fixture
def pair_files(tmp_path):
    left, right, d = slanted_plane_pair(240, 180, texture_scale=2.0)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), right)
    write_pfm(tmp_path / "gt.pfm", d.astype(np.float32))
    cv2.imwrite(str(tmp_path / "gt.png"), np.rint(4 * d).astype(np.uint8))
    return tmp_path


def test_features_table_csv_matches_and_plot(cli, pair_files):
    t = pair_files
    t0 = time.perf_counter()
    code, out, err = cli("features", t / "left.png", t / "right.png", "--methods", "sift,qdmatch,surf",
                         "--gt", t / "gt.pfm", "--csv", t / "table.csv", "--matches-out", t / "m",
                         "--plot", t / "spread.png")
    wall = time.perf_counter() - t0
    assert code == 0, err
    for col in ("t1 (s)", "num1", "t2 (s)", "num2", "t (s)", "prop (s)", "resamp (s)", "num",
                "distrib", "<=1px GT"):
        assert col in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.split()}
    assert "sift" in lines and "qdmatch" in lines and "surf" in lines
    with open(t / "table.csv") as fh:
        rows = {r["method"]: r for r in csv.DictReader(fh)}
    assert list(rows) == ["sift", "qdmatch", "surf"]
    assert rows["sift"]["propagation_s"] == "" and 0 < float(rows["qdmatch"]["propagation_s"]) < wall
    assert float(rows["qdmatch"]["correct_pct"]) >= 95.0
    assert float(rows["qdmatch"]["distribution_pct"]) > float(rows["sift"]["distribution_pct"])
    xl, xr = read_matches(t / "m" / "qdmatch.csv")
    assert len(xl) == int(rows["qdmatch"]["num"]) and xl.shape == xr.shape == (len(xl), 2)
    assert (t / "m" / "sift.csv").read_text().startswith("x_left,y_left,x_right,y_right")
    assert (t / "spread.png").stat().st_size > 1000


def test_features_without_gt_scores_against_the_pooled_epipolar_geometry(cli, pair_files):
    t = pair_files
    code, out, err = cli("features", t / "left.png", t / "right.png", "--methods", "sift,orb")
    assert code == 0, err
    assert "<=1px epi" in out and "epipolar line" in out


def test_integer_gt_needs_a_scale_and_then_works(cli, pair_files):
    t = pair_files
    code, _, err = cli("features", t / "left.png", t / "right.png", "--methods", "sift",
                       "--gt", t / "gt.png")
    assert code == 2 and "--gt-scale" in err
    code, out, err = cli("features", t / "left.png", t / "right.png", "--methods", "sift",
                         "--gt", t / "gt.png", "--gt-scale", "4", "--csv", t / "s.csv")
    assert code == 0, err
    with open(t / "s.csv") as fh:
        row = next(csv.DictReader(fh))
    assert float(row["correct_pct"]) > 90.0


def test_textureless_pair_gives_an_empty_row_with_a_reason(cli, tmp_path):
    flat = np.full((120, 160), 80, np.uint8)
    cv2.imwrite(str(tmp_path / "a.png"), flat)
    cv2.imwrite(str(tmp_path / "b.png"), flat)
    code, out, err = cli("features", tmp_path / "a.png", tmp_path / "b.png", "--methods", "qdmatch")
    assert code == 0, err
    row = next(ln for ln in out.splitlines() if ln.startswith("qdmatch"))
    assert row.split()[-3] == "0"                     # num
    assert "no seeds for propagation" in out and "texture" in out


def test_bad_input_exits_2_with_one_line(cli, tmp_path, pair_files):
    t = pair_files
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((50, 60), np.uint8))
    code, out, err = cli("features", t / "left.png", tmp_path / "small.png")
    assert code == 2 and "image sizes differ" in err and len(err.strip().splitlines()) == 1
    code, out, err = cli("features", t / "left.png", t / "right.png", "--methods", "sift,brisk")
    assert code == 2 and "unknown matching method 'brisk'" in err
    code, out, err = cli("features", t / "left.png", t / "nothere.png")
    assert code == 2 and "nothere.png" in err
