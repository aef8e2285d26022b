"""The paper run's Markdown report: each number of the run beside the number the paper prints."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from canopy_stereo.pipeline.paper.numbers import (
    PAPER_FEATURE_TABLES,
    PAPER_LEAVES,
    PAPER_TABLE1,
)


def _f(x, digits=2, suffix=""):
    if x is None:
        return "/"
    if isinstance(x, (int, np.integer)):
        return f"{int(x)}{suffix}"
    return f"{float(x):.{digits}f}{suffix}"


def _feature_table_md(info: dict) -> list[str]:
    paper = PAPER_FEATURE_TABLES[info["paper_table"]]
    basis = {"gt": "correct (<= 1 px of the true right pixel)",
             "epipolar": "correct (<= 1 px of the epipolar line)"}.get(info["basis"], "correct")
    leaf = any("leaf_cells_pct" in v for v in info["rows"])
    lines = ["| method | t1 (s) | num1 | t2 (s) | num2 | t (s) | propagation (s) | resample (s) "
             f"| num | distribution | {basis} |" + (" leaf cells reached |" if leaf else "")
             + " paper num | paper distribution |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if leaf else "")]
    for v in info["rows"]:
        p = paper.get(v["method"])
        empty = v["num"] == 0 and v["num1"] == 0 and v["num2"] == 0
        cells = ([v["method"]] + (["-"] * 7 if empty else
                                  [_f(v["t1_s"]), _f(v["num1"]), _f(v["t2_s"]), _f(v["num2"]),
                                   _f(v["t_s"]), _f(v["propagation_s"]), _f(v["resample_s"])])
                 + [_f(v["num"]), _f(v["distribution_pct"], 2, " %"),
                    _f(v["correct_pct"], 1, " %") if v["correct_pct"] is not None else "-"]
                 + ([("-" if empty else _f(v["leaf_cells_pct"], 1, " %"))] if leaf else [])
                 + [_f(p[7]) if p else "-", _f(p[8], 2, " %") if p else "-"])
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _spread_summary_md(features: dict) -> list[str]:
    """Quasi-dense spread per scene next to the sparse methods of the run (from Tables 2-4)."""
    methods = [m for m in ("sift", "asift", "qdmatch")
               if any(v["method"] == m for info in features.values() for v in info["rows"])]
    L = ["### Quasi-dense spread per scene", "",
         "Distribution (share of 8x8-pixel cells holding a match) and matches of each method, "
         "from the tables above; qdmatch's share correct beside it; the paper's qdmatch on its "
         "own pair of the same kind.", "",
         "| scene | " + " | ".join(f"{m} distribution | {m} num" for m in methods)
         + " | qdmatch correct | paper qdmatch distribution | paper qdmatch num |",
         "|---|" + "---|---|" * len(methods) + "---|---|---|"]
    for scene, info in features.items():
        rows = {v["method"]: v for v in info["rows"]}
        cells = [scene]
        for m in methods:
            v = rows.get(m)
            cells += (["-", "-"] if v is None else [_f(v["distribution_pct"], 2, " %"), _f(v["num"])])
        qd = rows.get("qdmatch")
        cells.append(_f(qd["correct_pct"], 1, " %") if qd and qd["correct_pct"] is not None else "-")
        p = PAPER_FEATURE_TABLES[info["paper_table"]]["qdmatch"]
        cells += [_f(p[8], 2, " %"), _f(p[7])]
        L.append("| " + " | ".join(cells) + " |")
    return L + [""]


def format_report(numbers: dict) -> str:
    """The Markdown report of a run (every figure of this run next to the paper's)."""
    L = []
    env = numbers["environment"]
    L += ["# Ni & Burks, reproduced by canopy-stereo", "",
          f"Mode: **{numbers['mode']}**, seed {numbers['seed']}; total {numbers['timings_s']['total']:.1f} s "
          f"on {env['processor']} (Python {env['python']}, OpenCV {env['opencv']}, numba {env['numba']}).",
          "Every number below comes from this run; the paper's printed numbers are quoted beside them. "
          "Lengths in mm, times in seconds (this machine; the paper used a Core i7-3630QM and a GPU "
          "for qdmatch).", ""]

    # Table 1
    cal = numbers["calibration"]
    L += ["## Table 1 and Figure 5: calibration in the world frame", ""]
    if cal.get("available"):
        skipped = cal["pairs_skipped"]
        L += [f"{cal['placements']} of the paper's {cal['placements_paper']} chessboard placements "
              "(7x5 inner corners, 50 mm squares, along the three lines of the floor sheet) rendered "
              "through the paper's rig with 0.7 px blur and noise sigma 2 grey levels; board found in "
              f"{cal['pairs_used']} pairs"
              + (f" (skipped: {', '.join(f'pair {p}: {r}' for p, r in skipped)})" if skipped else "")
              + f"; Gold Standard calibration; the {cal['corners']} corners triangulated back with "
              "each placement left out of its own calibration (distance "
              f"{cal['distance_range'][0]:.0f}-{cal['distance_range'][1]:.0f} mm). Reprojection RMS "
              f"{cal['rms_left_px']:.3f} px (left), {cal['rms_right_px']:.3f} px (right); camera "
              f"centres {cal['camera_centre_error_mm'][0]:.2f} / {cal['camera_centre_error_mm'][1]:.2f} "
              "mm from the true rig's.", "",
              "| axis | mean absolute error (mm) | std (mm) | paper mean (mm) | paper std (mm) |",
              "|---|---|---|---|---|"]
        for axis in "XYZ":
            m, s = cal["table1"][axis]
            pm, ps = PAPER_TABLE1[axis]
            L.append(f"| {axis} | {m:.3f} | {s:.3f} | {pm:.2f} | {ps:.2f} |")
        L += ["", f"![Figure 5: error against distance]({cal['figure']})", "",
              f"![a rendered calibration pair]({cal['sample_figure']})", ""]
    else:
        L += [f"**Not reproduced in this run:** {cal.get('reason', 'unavailable')}.", "",
              "Paper (Table 1): mean absolute error X 0.42, Y 0.36, Z 2.78 mm "
              "(std 0.35, 0.31, 1.74 mm).", ""]

    # Tables 2-4
    L += ["## Tables 2-4: feature detection and matching", "",
          "distribution = share of 8x8-pixel cells of the left image holding a match (the paper's "
          "definition). Matches of every method are in `matches/<scene>/<method>.csv`. The paper's "
          "pairs are not published; each table uses the shipped pair closest to the paper's. On the "
          "rendered pairs, leaf cells reached = share of the cells that are mostly leaf holding a "
          "match (the distribution also counts the textured background).", ""]
    for _scene, info in numbers["features"].items():
        w, h = info["image_size"]
        L += [f"### Table {info['table']}: {info['source']} ({w}x{h}) — paper: '{info['paper_table']}'",
              ""] + _feature_table_md(info)
        notes = [f"{v['method']}: {v['note']}" for v in info["rows"] if v.get("note")]
        if notes:
            L += ["", "Notes: " + "; ".join(notes)]
        L += ["", f"![spread of the matches, Table {info['table']}]({info['figure']})", ""]
    if numbers["features"]:
        L += _spread_summary_md(numbers["features"])

    # Figure 11
    r = numbers["rectification"]
    L += ["## Figure 11: Hartley rectification", "",
          f"{r['scene']}: {r['matches']} quasi-dense matches, {r['f_inliers']} consistent with F "
          "(RANSAC, 1 px); Hartley's homographies. Angles of the three epipolar lines to the image "
          "rows: before " + ", ".join(f"{a:.2f}" for a in r["angles_before_deg"]) + " deg, after "
          + ", ".join(f"{a + 0.0:.3f}" if abs(a) >= 5e-4 else "0.000" for a in r["angles_after_deg"])
          + " deg. Residual vertical "
          f"disparity of {r['truth_points']} exact correspondences after rectification: median "
          f"{r['median_abs_dv_px']:.3f} px, 90th percentile {r['p90_abs_dv_px']:.3f} px.", "",
          f"![Figure 11]({r['figure']})", ""]

    # Figures 15-17
    L += ["## Figures 15-17: rectified pairs and reconstructions", "",
          "Fusiello rectification from the rig's P matrices, ELAS disparity, triangulation in the "
          "world frame; the pictures show the plant points (automatic plant mask) turned 30 degrees "
          "about the plant. Clouds are in `clouds/<scene>.ply`.", "",
          "| scene | points | plant points | median range error vs truth (mm) | relative | seconds |",
          "|---|---|---|---|---|---|"]
    recs = dict(numbers["fig15"])
    recs.update(numbers["fig17"])
    for _key, info in recs.items():
        err = info.get("median_abs_range_error_mm")
        rel = info.get("median_rel_range_error_pct")
        L.append(f"| {info['title']} | {info['points']} | {info['plant_points']} | "
                 f"{_f(err, 2) if err is not None else 'no truth'} | "
                 f"{_f(rel, 2, ' %') if rel is not None else '-'} | {info['seconds']:.1f} |")
    figs = []
    for info in recs.values():
        if info.get("figure") and info["figure"] not in figs:
            figs.append(info["figure"])
    L.append("")
    L.append(f"![Figure 16: citrus branch pair]({numbers['fig16']['figure']})")
    L.append("")
    for fig in figs:
        L += [f"![{Path(fig).stem}]({fig})", ""]

    # leaves
    lv = numbers["leaves"]
    L += ["## Figures 20-22: the two marked croton leaves", "",
          f"{lv['scene']}: leaf surface width and length measured on the reconstructed cloud "
          "(the leaf pixels are the marked leaves of the rendered scene, as the paper marked them "
          "by hand). Truth = the rendered leaves' surface sizes (the paper's ruler values).", "",
          "| leaf | truth W x L (mm) | this run W x L (mm) | error W / L | paper ruler W x L | "
          "paper 3D W x L | paper error W / L |", "|---|---|---|---|---|---|---|"]
    for e in lv["leaves"]:
        p = PAPER_LEAVES.get(e["id"])
        L.append(f"| {e['id']} | {e['truth_width']:.2f} x {e['truth_length']:.2f} | "
                 f"{e['width']:.2f} x {e['length']:.2f} | "
                 f"{e['width_error_pct']:+.2f} % / {e['length_error_pct']:+.2f} % | "
                 + (f"{p['ruler'][0]:.1f} x {p['ruler'][1]:.1f} | {p['paper'][0]:.2f} x {p['paper'][1]:.2f} | "
                    f"{e['paper_width_error_pct']:+.2f} % / {e['paper_length_error_pct']:+.2f} % |"
                    if p else "- | - | - |"))
    L += ["", f"![Figure 21: measured leaves]({lv['figure']})", ""]

    # timings
    L += ["## Run time", "", "| stage | seconds |", "|---|---|"]
    for k, v in numbers["timings_s"].items():
        L.append(f"| {k} | {v:.1f} |")
    L.append("")
    return "\n".join(L)
