"""The paper's results reproduced on what the package ships (``canopy-stereo paper``).

:func:`run_paper` runs every experiment of Ni & Burks that the package can repeat
without the authors' photographs, writes the figures and a Markdown report that
puts each number of this run next to the number the paper prints, and returns the
run's numbers (also written as ``report.json``):

* Table 1 and Figure 5: the world-rig calibration on rendered photographs of the
  paper's layout (chessboard placements along three lines), through the paper's rig;
* Tables 2-4: the feature study (:mod:`canopy_stereo.features.study`) on the shipped
  plant pairs: Middlebury "Plants" (real, bundled; stands in for the aloe of
  Table 2), the synthetic citrus branch (small leaves; for the banyan of Table 3)
  and the synthetic croton (Table 4), with correctness against the exact
  correspondences of the rendered pairs;
* Figure 11: epipolar lines before and after Hartley rectification (from
  quasi-dense matches) of the rendered croton pair;
* Figures 15-17: rectified pairs and the reconstructed clouds as pictures (croton,
  the real Plants pair, the citrus branch);
* the two marked croton leaves (Figures 20-22): width and length measured on the
  reconstruction, against the rendered truth (the ruler: 97 x 160 and 86 x 145 mm)
  and the paper's MeshLab figures.

The only constants are the paper's printed numbers (:data:`PAPER_TABLE1`,
:data:`PAPER_FEATURE_TABLES`, :data:`PAPER_LEAVES`); everything else is measured by
the run. ``quick=True`` is the reduced mode for CI (fewer methods, placements and
scenes). Lengths are millimetres (the rigs' world unit).
"""
from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.progress import Progress

# ----------------------------------------------------------------------------- the paper's numbers

#: Table 1: axis -> (mean absolute error, standard deviation), mm.
PAPER_TABLE1 = {"X": (0.42, 0.35), "Y": (0.36, 0.31), "Z": (2.78, 1.74)}

#: Columns of Tables 2-4 (the paper's), in order.
PAPER_COLUMNS = ("t1_s", "num1", "t2_s", "num2", "t_s", "propagation_s", "resample_s", "num",
                 "distribution_pct")

#: Tables 2-4: table -> method -> the paper's row (None where it prints "/").
PAPER_FEATURE_TABLES = {
    "aloe": {
        "harris-affine": (0.27, 279, 0.27, 349, 0.03, None, None, 31, 0.42),
        "hessian-affine": (0.17, 344, 0.16, 298, 0.03, None, None, 36, 0.58),
        "sift": (1.25, 3284, 1.28, 3384, 0.23, None, None, 609, 9.54),
        "asift": (15.04, 20281, 16.70, 25704, 1.56, None, None, 2377, 18.98),
        "surf": (0.23, 401, 0.24, 447, 0.09, None, None, 100, 2.00),
        "qdmatch": (0.15, 5705, 0.07, 4823, 0.06, 2.76, 3.40, 1624, 31.08),
    },
    "banyan": {
        "harris-affine": (0.36, 1137, 0.35, 1028, 0.08, None, None, 19, 0.31),
        "hessian-affine": (0.28, 1367, 0.28, 1379, 0.09, None, None, 34, 0.54),
        "sift": (1.17, 2307, 1.34, 3467, 0.17, None, None, 148, 2.35),
        "asift": (18.38, 3118, 18.35, 31358, 2.41, None, None, 663, 6.73),
        "surf": (0.39, 808, 0.38, 752, 0.16, None, None, 64, 1.25),
        "qdmatch": (0.10, 3772, 0.08, 4812, 0.06, 3.32, 3.82, 1423, 27.25),
    },
    "croton": {
        "harris-affine": (0.36, 989, 0.36, 1006, 0.06, None, None, 110, 1.73),
        "hessian-affine": (0.29, 1131, 0.32, 1306, 0.07, None, None, 155, 2.63),
        "sift": (1.12, 2092, 1.11, 2012, 0.13, None, None, 451, 6.88),
        "asift": (16.63, 26960, 17.03, 27972, 2.06, None, None, 4386, 22.88),
        "surf": (0.49, 1039, 0.51, 1055, 0.22, None, None, 326, 6.27),
        "qdmatch": (0.11, 2418, 0.05, 2500, 0.02, 2.03, 3.30, 1546, 28.08),
    },
}

#: The two marked croton leaves: id -> ruler (width, length) and the paper's
#: reconstruction (width, length), mm (Figures 21 and 22).
PAPER_LEAVES = {1: {"ruler": (97.0, 160.0), "paper": (94.46, 156.24)},
                2: {"ruler": (86.0, 145.0), "paper": (87.04, 144.00)}}

#: Feature methods of the full and the quick run.
FULL_METHODS = ("harris-affine", "hessian-affine", "sift", "asift", "surf", "orb", "akaze",
                "qdmatch")
QUICK_METHODS = ("sift", "asift", "qdmatch")

#: Placements of the world-rig calibration: full = the paper's 45, quick = 9 of them
#: (three per line, spread along each line).
QUICK_PLACEMENTS = 9

#: Table number, paper table and shipped pair of the feature study.
FEATURE_SCENES = (
    ("2", "aloe", "plants", "Middlebury 2014 Plants (real, bundled in bags/plants.mcap)"),
    ("3", "banyan", "citrus_branch", "synthetic citrus branch (canopy_stereo.sim, small leaves)"),
    ("4", "croton", "croton", "synthetic croton (canopy_stereo.sim, the paper's rig)"),
)


# ----------------------------------------------------------------------------- data


@dataclass
class StereoPair:
    """A shipped stereo pair: images, rig and (rendered scenes) the exact truth."""

    key: str
    title: str
    left: np.ndarray
    right: np.ndarray
    rig: object
    sim: object = None                   # SimResult for rendered scenes


def plants_pair() -> StereoPair:
    """The bundled Middlebury "Plants" pair and its rig (from ``bags/plants.mcap``;
    the source tree's ``examples/plants`` PNGs when the ROS message packages are absent)."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_rig

    rig = load_rig(bundled_rig("plants"))
    folder = Path(__file__).resolve().parents[2] / "examples" / "plants"
    try:
        from canopy_stereo.bag import BagReader
        from canopy_stereo.ros.bundled import LEFT_TOPIC, RIGHT_TOPIC, bundled_bag
        from canopy_stereo.ros.convert import msg_to_image

        bag = BagReader(bundled_bag("plants"))
        left = next(iter(bag.read(LEFT_TOPIC)))[1]
        right = next(iter(bag.read(RIGHT_TOPIC)))[1]
        left, right = msg_to_image(left, ("bgr8",)), msg_to_image(right, ("bgr8",))
    except ImportError:
        from canopy_stereo.io.images import read_image

        if not (folder / "left.png").is_file():
            raise CanopyStereoError("the Plants pair needs the ROS message packages (pip install "
                                    "-e '.[ros]') or the source tree's examples/plants") from None
        left, right = read_image(folder / "left.png"), read_image(folder / "right.png")
    return StereoPair("plants", "Middlebury 2014 Plants (real)", np.ascontiguousarray(left),
                      np.ascontiguousarray(right), rig)


def rendered_pair(scene: str, seed: int = 0) -> StereoPair:
    """A scene of :mod:`canopy_stereo.sim` through the paper's rig."""
    from canopy_stereo.sim import render_scene

    sim = render_scene(scene, seed=seed)
    return StereoPair(scene, f"synthetic {scene.replace('_', ' ')} (seed {seed})", sim.left,
                      sim.right, sim.rig, sim)


# ----------------------------------------------------------------------------- sections


def section_calibration(out: Path, quick: bool, seed: int, progress: Progress) -> dict:
    """Table 1 and Figure 5 from rendered photographs of the paper's layout."""
    try:
        from canopy_stereo.geometry import world_rig
        from canopy_stereo.sim import calibration as sim_calibration
    except ImportError as exc:
        return {"available": False,
                "reason": f"the world-rig calibration is not part of this build ({exc})"}
    return _run_world_rig(world_rig, sim_calibration, out, quick, seed, progress)


def _run_world_rig(world_rig, sim_calibration, out: Path, quick: bool, seed: int,
                   progress: Progress) -> dict:
    from dataclasses import replace

    from canopy_stereo.geometry.board_placements import Placements, paper_layout_placements
    from canopy_stereo.geometry.camera import camera_centre
    from canopy_stereo.sim import resolve_rig

    rig = resolve_rig(None)
    placements = paper_layout_placements(pattern=(7, 5), square=50.0)
    total = len(placements)
    if quick:
        keep = np.unique(np.linspace(0, total - 1, QUICK_PLACEMENTS).round().astype(int))
        chosen = [placements[int(i)] for i in keep]
        # pairs are numbered by image order: renumber the kept placements 0..n-1
        placements = Placements(placements.pattern, placements.square, placements.unit,
                                tuple(replace(p, pair=k) for k, p in enumerate(chosen)))
    progress.detail(f"rendering {len(placements)} of the paper's {total} chessboard placements "
                    "through the paper's rig (0.7 px blur, noise sigma 2)")
    pairs = sim_calibration.render_calibration_scene(rig, placements, blur_px=0.7, noise_sigma=2.0,
                                                     seed=seed, progress=progress.detail)
    lefts = [a for a, _ in pairs]
    rights = [b for _, b in pairs]
    folder = out / "calibration_images"
    folder.mkdir(parents=True, exist_ok=True)
    for k in (0, len(pairs) // 2, len(pairs) - 1):
        cv2.imwrite(str(folder / f"left{k:02d}.png"), lefts[k])
        cv2.imwrite(str(folder / f"right{k:02d}.png"), rights[k])
    progress.detail("corners, Gold Standard calibration, leave-one-placement-out check")
    cal = world_rig.calibrate_world_rig(lefts, rights, placements, pattern=(7, 5), square=50.0,
                                        progress=progress.detail)
    t1 = cal.table1
    table = {axis: (float(t1.mean_abs[i]), float(t1.std[i])) for i, axis in enumerate("XYZ")}
    fig = out / "figures" / "fig05_calibration_errors.png"
    world_rig.plot_world_rig_errors(cal, fig)
    sample = out / "figures" / "fig04_calibration_pair.png"
    from canopy_stereo.pipeline.figures import panel_row

    mid = len(pairs) // 2
    mark = placements[mid].label.split(":")[0] or f"placement {mid}"
    cv2.imwrite(str(sample), panel_row([lefts[mid], rights[mid]],
                                       [f"rendered left, {mark}", "rendered right"]))
    centre_err = [float(np.linalg.norm(camera_centre(cal.rig.P_left) - camera_centre(rig.P_left))),
                  float(np.linalg.norm(camera_centre(cal.rig.P_right) - camera_centre(rig.P_right)))]
    return {"available": True, "placements": len(placements), "placements_paper": total,
            "pairs_used": len(cal.used_pairs), "pairs_skipped": [list(x) for x in cal.skipped],
            "corners": int(len(t1.errors)), "table1": table,
            "max_abs": {axis: float(t1.max_abs[i]) for i, axis in enumerate("XYZ")},
            "distance_range": [float(t1.distance.min()), float(t1.distance.max())],
            "rms_left_px": float(cal.rms_left), "rms_right_px": float(cal.rms_right),
            "camera_centre_error_mm": centre_err,
            "figure": str(fig.relative_to(out)), "sample_figure": str(sample.relative_to(out))}


def section_features(out: Path, pairs: dict, methods, progress: Progress) -> dict:
    """Tables 2-4: the feature study on the shipped plant pairs."""
    from canopy_stereo.features.study import plot_spread, row_values, run_study, write_csv, write_matches
    from canopy_stereo.sim.correspondence import true_right_pixels

    result = {}
    for number, paper_key, scene, source in FEATURE_SCENES:
        if scene not in pairs:
            continue
        pair = pairs[scene]
        truth = true_right_pixels(pair.sim) if pair.sim is not None else None
        progress.detail(f"Table {number} ({paper_key} -> {scene}): {', '.join(methods)}")
        rows = run_study(pair.left, pair.right, methods=methods, gt_right_pixels=truth,
                         progress=lambda m, scene=scene: progress.detail(f"  {scene}: {m}"))
        folder = out / "matches" / scene
        for row in rows:
            write_matches(row.result, folder)
        write_csv(rows, out / "tables" / f"table{number}_{scene}.csv")
        fig = plot_spread(rows, pair.left, out / "figures" / f"table{number}_{scene}_spread.png")
        leaf_cells = _leaf_cells(pair.sim) if pair.sim is not None else None
        vals = []
        for row in rows:
            v = row_values(row)
            v["n_evaluated"] = row.n_evaluated
            if leaf_cells is not None:
                v["leaf_cells_pct"] = 100.0 * _cells_reached(row.result.x_left, leaf_cells)
            v["matches_csv"] = str((folder / f"{row.result.method}.csv").relative_to(out))
            vals.append(v)
        result[scene] = {"table": number, "paper_table": paper_key, "source": source,
                         "image_size": list(pairs[scene].left.shape[1::-1]),
                         "basis": rows[0].correct_basis if rows else "",
                         "rows": vals, "figure": str(fig.relative_to(out))}
    return result


def _leaf_cells(sim, cell: int = 8) -> np.ndarray:
    """(ny, nx) bool: 8x8-pixel cells of the left image that are mostly leaf (rendered truth)."""
    from canopy_stereo.sim import LABEL_NAMES

    leaf_label = next(k for k, v in LABEL_NAMES.items() if v == "leaf")
    leaf = sim.labels_left == leaf_label
    h, w = leaf.shape
    ny, nx = -(-h // cell), -(-w // cell)
    pad = np.zeros((ny * cell, nx * cell))
    pad[:h, :w] = leaf
    return pad.reshape(ny, cell, nx, cell).mean(axis=(1, 3)) > 0.5


def _cells_reached(x_left, cells: np.ndarray, cell: int = 8) -> float:
    """Share of the True ``cells`` holding at least one of the points (pixels, the paper's
    cell convention: pixel ``i`` covers ``[i - 0.5, i + 0.5)``)."""
    if not cells.any():
        return 0.0
    x = np.asarray(x_left, np.float64).reshape(-1, 2)
    cx = np.floor((x[:, 0] + 0.5) / cell).astype(int)
    cy = np.floor((x[:, 1] + 0.5) / cell).astype(int)
    ok = (cx >= 0) & (cx < cells.shape[1]) & (cy >= 0) & (cy < cells.shape[0])
    used = np.zeros_like(cells)
    used[cy[ok], cx[ok]] = True
    return float((used & cells).sum() / cells.sum())


def section_rectification(out: Path, pair: StereoPair, progress: Progress) -> dict:
    """Figure 11: Hartley rectification from quasi-dense matches, epipolar lines drawn."""
    from canopy_stereo.features import match_pair
    from canopy_stereo.geometry.rectification import StereoRectifier
    from canopy_stereo.geometry.rig_rectification import rectification_for_rig
    from canopy_stereo.geometry.triangulation import apply_homography
    from canopy_stereo.pipeline.figures import epipolar_figure
    from canopy_stereo.sim.correspondence import true_right_pixels

    progress.detail("quasi-dense matches -> F (RANSAC) -> Hartley homographies")
    m = match_pair(pair.left, pair.right, method="qdmatch")
    rect = rectification_for_rig(pair.rig, method="hartley", matches=(m.x_left, m.x_right))
    left_r, right_r = StereoRectifier(pair.rig, rect).rectify(pair.left, pair.right)
    # residual vertical disparity after rectification, on the exact correspondences
    truth = true_right_pixels(pair.sim)
    h, w = truth.shape[:2]
    vv, uu = np.mgrid[0:h:4, 0:w:4]
    tr = truth[vv, uu].reshape(-1, 2)
    ok = np.all(np.isfinite(tr), axis=1)
    xl = np.column_stack([uu.ravel(), vv.ravel()]).astype(np.float64)[ok]
    dv = apply_homography(rect.H_left, xl)[:, 1] - apply_homography(rect.H_right, tr[ok])[:, 1]
    # three feature points spread from top to bottom (the paper's Figure 11)
    inl = np.abs(m.x_left[:, 1][:, None] - np.array([0.2, 0.5, 0.8]) * h)
    pick = [int(np.argmin(inl[:, k] + 0.01 * np.abs(m.x_left[:, 0] - 0.5 * w))) for k in range(3)]
    fig, angles = epipolar_figure(pair.left, pair.right, left_r, right_r, rect.F, rect.H_left,
                                  rect.H_right, m.x_left[pick])
    path = out / "figures" / "fig11_epipolar_lines.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), fig)
    return {"scene": pair.title, "matches": int(m.num), "f_inliers": int(rect.n_inliers),
            "points": [[float(a), float(b)] for a, b in m.x_left[pick]],
            "angles_before_deg": angles["angles_before"], "angles_after_deg": angles["angles_after"],
            "truth_points": int(ok.sum()),
            "median_abs_dv_px": float(np.median(np.abs(dv))),
            "p90_abs_dv_px": float(np.percentile(np.abs(dv), 90)),
            "figure": str(path.relative_to(out))}


def _plant_mask(pair: StereoPair, recon):
    """The measuring pipeline's automatic plant mask
    (:func:`~canopy_stereo.measure.plant.automatic_plant_mask`) of the left image."""
    from canopy_stereo.measure.plant import automatic_plant_mask

    try:
        return automatic_plant_mask(pair.left, recon.organized, pair.rig)
    except CanopyStereoError:
        return None


def _depth_error(pair: StereoPair, recon, mask) -> dict:
    """Errors of the reconstructed points against the rendered truth at the same pixels."""
    from canopy_stereo.geometry.camera import camera_centre

    truth = pair.sim.xyz_left
    ok = np.all(np.isfinite(recon.organized), axis=2) & np.all(np.isfinite(truth), axis=2)
    if mask is not None:
        ok &= mask
    C = camera_centre(pair.rig.P_left)
    d_est = np.linalg.norm(recon.organized[ok] - C, axis=1)
    d_true = np.linalg.norm(truth[ok] - C, axis=1)
    err = np.abs(d_est - d_true)
    return {"points_with_truth": int(ok.sum()),
            "median_abs_range_error_mm": float(np.median(err)) if len(err) else None,
            "median_rel_range_error_pct": float(100 * np.median(err / d_true)) if len(err) else None}


def section_reconstruction(out: Path, pairs: dict, figure: str, keys, progress: Progress,
                           recon_cache: dict) -> dict:
    """Figures 15-17: rectified pair | reconstructed cloud (plant points) per scene."""
    from canopy_stereo.io.ply import write_ply
    from canopy_stereo.pipeline.figures import panel_row, render_cloud
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    result = {}
    rows = []
    for key in keys:
        if key not in pairs:
            continue
        pair = pairs[key]
        progress.detail(f"{pair.title}: Fusiello rectification, ELAS, triangulation")
        t = time.perf_counter()
        recon = recon_cache.get(key) or reconstruct_pair(pair.left, pair.right, pair.rig)
        recon_cache[key] = recon
        t_rec = time.perf_counter() - t
        mask = _plant_mask(pair, recon)
        sel = np.ones(len(recon.points), bool)
        if mask is not None:
            sel = mask[recon.pixels[:, 1], recon.pixels[:, 0]]
        pts, cols = recon.points[sel], recon.colors[sel]
        cloud_img = render_cloud(pts, cols, pair.rig.P_left, yaw_deg=30.0, pitch_deg=15.0,
                                 size=(pair.left.shape[1], pair.left.shape[0]))
        row = panel_row([recon.rectified[0], recon.rectified[1], cloud_img],
                        ["rectified left", "rectified right",
                         f"3D result, {len(pts)} plant points, turned 30 deg"])
        rows.append(row)
        ply = out / "clouds" / f"{key}.ply"
        write_ply(ply, pts, colors=cols, unit=pair.rig.world_unit,
                  comments=[f"canopy-stereo paper: {pair.title}, plant points"])
        info = {"title": pair.title, "points": int(len(recon.points)), "plant_points": int(len(pts)),
                "plant_mask": "auto" if mask is not None else "none (segmentation failed)",
                "disp_range": [int(v) for v in recon.disp_range], "seconds": t_rec,
                "cloud": str(ply.relative_to(out))}
        if pair.sim is not None:
            info.update(_depth_error(pair, recon, mask))
        result[key] = info
    if rows:
        width = max(r.shape[1] for r in rows)
        rows = [np.hstack([r, np.full((r.shape[0], width - r.shape[1], 3), 255, np.uint8)])
                if r.shape[1] < width else r for r in rows]
        sep = np.full((6, width, 3), 255, np.uint8)
        img = rows[0]
        for r in rows[1:]:
            img = np.vstack([img, sep, r])
        path = out / "figures" / f"{figure}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), img)
        for info in result.values():
            info["figure"] = str(path.relative_to(out))
    return result


def section_leaves(out: Path, pair: StereoPair, recon_cache: dict, progress: Progress) -> dict:
    """The two marked croton leaves measured on the reconstruction (Figures 20-22)."""
    from canopy_stereo.geometry.camera import project
    from canopy_stereo.measure import measure_leaf
    from canopy_stereo.pipeline.figures import label, panel_row
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    recon = recon_cache.get(pair.key) or reconstruct_pair(pair.left, pair.right, pair.rig)
    recon_cache[pair.key] = recon
    sim = pair.sim
    leaves = []
    crops = []
    for lf in sorted((x for x in sim.truth["leaves"] if x["marked"]), key=lambda x: x["id"]):
        progress.detail(f"leaf {lf['id']}: surface length and width on the reconstruction")
        inside = sim.leaf_ids_left == lf["id"]
        m = measure_leaf(recon.organized, inside, leaf_id=lf["id"], camera=pair.rig.P_left)
        entry = {"id": int(lf["id"]), "truth_width": float(lf["width"]),
                 "truth_length": float(lf["length"]), "width": float(m.width),
                 "length": float(m.length), "reliable": bool(m.extra.get("reliable", True)),
                 "pixels": int(inside.sum())}
        entry["width_error_pct"] = 100.0 * (entry["width"] / entry["truth_width"] - 1.0)
        entry["length_error_pct"] = 100.0 * (entry["length"] / entry["truth_length"] - 1.0)
        paper = PAPER_LEAVES.get(int(lf["id"]))
        if paper is not None:
            entry["paper_width_error_pct"] = 100.0 * (paper["paper"][0] / paper["ruler"][0] - 1.0)
            entry["paper_length_error_pct"] = 100.0 * (paper["paper"][1] / paper["ruler"][1] - 1.0)
        leaves.append(entry)
        # picture: the leaf on the left image with its measured length and width drawn
        img = pair.left.copy()
        contour_mask = inside.astype(np.uint8)
        cnts, _ = cv2.findContours(contour_mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, cnts, -1, (255, 255, 255), 1, cv2.LINE_AA)
        for ends, col, _text in ((m.ends, (0, 0, 255), f"length {m.length:.1f} mm"),
                                (m.width_ends, (255, 128, 0), f"width {m.width:.1f} mm")):
            uv = project(pair.rig.P_left, np.asarray(ends, np.float64))
            p0, p1 = (tuple(int(round(c)) for c in p) for p in uv)
            cv2.line(img, p0, p1, col, 2, cv2.LINE_AA)
            cv2.circle(img, p0, 4, col, -1)
            cv2.circle(img, p1, 4, col, -1)
        v, u = np.nonzero(inside)
        pad = 40
        y0, y1 = max(0, v.min() - pad), min(img.shape[0], v.max() + pad)
        x0, x1 = max(0, u.min() - pad), min(img.shape[1], u.max() + pad)
        crop = np.ascontiguousarray(img[y0:y1, x0:x1])
        scale = 360 / crop.shape[0]
        crop = cv2.resize(crop, (max(1, int(crop.shape[1] * scale)), 360), interpolation=cv2.INTER_CUBIC)
        label(crop, f"leaf {lf['id']}: W {m.width:.1f} x L {m.length:.1f} mm", org=(4, 328))
        crops.append(crop)
    path = out / "figures" / "fig21_marked_leaves.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    if crops:
        cv2.imwrite(str(path), panel_row(crops))
    return {"scene": pair.title, "leaves": leaves, "figure": str(path.relative_to(out))}


# ----------------------------------------------------------------------------- the run


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


# ----------------------------------------------------------------------------- the report


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


__all__ = ["FEATURE_SCENES", "FULL_METHODS", "PAPER_FEATURE_TABLES", "PAPER_LEAVES", "PAPER_TABLE1",
           "QUICK_METHODS", "StereoPair", "format_report", "plants_pair", "rendered_pair",
           "run_paper"]
