"""The paper run's experiments, one function per table or figure group (each writes its figures
and returns its numbers)."""
from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.pipeline.paper.data import StereoPair
from canopy_stereo.pipeline.paper.numbers import (
    FEATURE_SCENES,
    PAPER_LEAVES,
    QUICK_PLACEMENTS,
)
from canopy_stereo.progress import Progress


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
