"""``canopy-stereo measure``: the report, CSV and plot of an organized cloud, and bad input (the
two-leaf scene with exact answers is test/support/scenes.py's)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from test.support.scenes import two_leaf_scene


@pytest.mark.slow
def test_cli_measure_writes_report_csv_and_plot(paper_rig, tmp_path, cli):
    import cv2

    org, lab, leaves = two_leaf_scene(paper_rig)
    np.save(tmp_path / "org.npy", org.astype(np.float32))
    cv2.imwrite(str(tmp_path / "ids.png"), np.where(lab <= 2, lab, 0).astype(np.uint8))
    code, out, err = cli("measure", tmp_path / "org.npy", "--leaf-ids", tmp_path / "ids.png",
                         "-o", tmp_path / "rep.json", "--csv", tmp_path / "l.csv",
                         "--plot", tmp_path / "v.png")
    assert code == 0, err
    rep = json.loads((tmp_path / "rep.json").read_text())
    assert [lf["id"] for lf in rep["leaves"]] == [1, 2]
    assert rep["leaves"][0]["length"] == pytest.approx(leaves[0].length, rel=0.005)
    assert rep["source"]["camera"] == "estimated"
    assert (tmp_path / "l.csv").is_file() and (tmp_path / "v.png").stat().st_size > 10000
    assert "height" in out and "wrote" in out


def test_cli_measure_bad_input_is_one_line(tmp_path, cli):
    bad = tmp_path / "x.ply"
    bad.write_text("not a ply")
    code, out, err = cli("measure", bad, "-o", tmp_path / "r.json")
    assert code == 2 and "is not a PLY file" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    np.save(tmp_path / "o.npy", np.zeros((6, 8, 3)))
    (tmp_path / "m.png").write_bytes(b"")
    import cv2

    cv2.imwrite(str(tmp_path / "m.png"), np.zeros((6, 8), np.uint8))
    code, _, err = cli("measure", tmp_path / "o.npy", "--mask", tmp_path / "m.png", "-o", tmp_path / "r.json")
    assert code == 2 and "mask is empty" in err
    cv2.imwrite(str(tmp_path / "m.png"), np.full((5, 5), 255, np.uint8))
    code, _, err = cli("measure", tmp_path / "o.npy", "--mask", tmp_path / "m.png", "-o", tmp_path / "r.json")
    assert code == 2 and "mask is 5x5 but the organized cloud is 8x6" in err
