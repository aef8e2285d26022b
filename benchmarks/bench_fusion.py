"""Multi-view fusion on the synthetic croton: coverage, registration error, leaf sizes, time.

Renders an N-view sequence of the croton (turntable or orbit) through the
paper's rig, reconstructs every view (``reconstruct_pair`` inside the true
plant mask), then

1. registers the views without their poses (features lifted to 3-D, robust
   point-to-plane ICP, pose-graph loop closure) and prints each view's pose
   error against the truth: translation at the plant centre (mm) and rotation
   (degrees), after expressing both in view 0's frame;
2. fuses the views with the true and with the registered poses and prints the
   share of the true leaf surface covered (a true surface sample is covered
   when a model point lies within ``--radius`` of it) for the fused model and
   for every single view, with the model's distance to the true leaves;
3. measures the marked leaves on the fused model and on view 0 alone, against
   the true length and width. A leaf's points are selected with the true blade
   (an ideal segmentation: within 6 mm of the blade along its normal, the depth
   noise, and within 1.5 mm of it across, so the outline is the true one to
   that tolerance), rendered into a virtual camera facing the leaf and
   measured by :func:`canopy_stereo.measure.leaf.measure_leaf`; the figure
   thus tests how completely and how faithfully the model covers the blade
   (holes, curvature), not the segmentation.

Usage: ``python benchmarks/bench_fusion.py [--views 8] [--mode turntable|orbit]
[--matcher sgbm|elas] [--voxel 2] [--seed 0]``. Prints figures; asserts nothing.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def virtual_grid(points, normal, centre, size=(480, 480), distance=400.0, pixel=0.5):
    """Organized cloud (H, W, 3) of ``points`` seen by a virtual pinhole camera facing them.

    The camera stands ``distance`` along ``normal`` from ``centre`` looking back at it,
    with a focal length giving ``pixel`` world units per pixel at that distance; each
    point is splatted into a 3x3 block (nearest depth wins), so a cloud sampled every
    few pixels becomes a hole-free grid. Returns ``(grid, mask, P)``.
    """
    from canopy_stereo.geometry.camera import compose_projection, point_depth, project

    n = normal / np.linalg.norm(normal)
    C = centre + distance * n
    z = -n
    x = np.cross([0.0, 1.0, 0.0], z)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.vstack([x, y, z])
    w, h = size
    f = distance / pixel
    K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
    P = compose_projection(K, R, C)
    uv = project(P, points)
    depth = point_depth(P, points)
    grid = np.full((h, w, 3), np.nan)
    zbuf = np.full((h, w), np.inf)
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            u = np.rint(uv[:, 0]).astype(int) + du
            v = np.rint(uv[:, 1]).astype(int) + dv
            ok = (u >= 0) & (v >= 0) & (u < w) & (v < h)
            order = np.argsort(-depth[ok])            # far first, near overwrite
            uu, vv, pp, dd = u[ok][order], v[ok][order], points[ok][order], depth[ok][order]
            nearer = dd < zbuf[vv, uu]
            zbuf[vv[nearer], uu[nearer]] = dd[nearer]
            grid[vv[nearer], uu[nearer]] = pp[nearer]
    mask = np.isfinite(zbuf)
    return grid, mask, P


def measure_on_points(points, truth_leaf):
    """Length and width of one leaf from its 3-D points (virtual camera facing the true leaf)."""
    import cv2

    from canopy_stereo.measure.leaf import measure_leaf

    normal = np.asarray(truth_leaf["pose"]["axes"])[2]
    centre = points.mean(axis=0)
    grid, mask, P = virtual_grid(points, normal, centre)
    mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0
    m = measure_leaf(grid, mask, leaf_id=truth_leaf["id"], camera=P, model="local", smoothing_px=3.0)
    return m.length, m.width


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--mode", choices=("turntable", "orbit"), default="turntable")
    ap.add_argument("--matcher", default="sgbm")
    ap.add_argument("--voxel", type=float, default=2.0, help="fusion voxel, mm")
    ap.add_argument("--radius", type=float, default=3.0, help="coverage radius, mm")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from scipy.spatial import cKDTree

    from canopy_stereo.fusion import (
        RegistrationSettings,
        evaluate_model,
        fuse_views,
        register_views,
        transform_error,
        view_from_reconstruction,
    )
    from canopy_stereo.geometry.transforms import invert_transform, transform_points
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair
    from canopy_stereo.sim.multiview import render_views, sample_leaf_surfaces

    t = time.perf_counter()
    seq = render_views("croton", None, n_views=args.views, mode=args.mode, seed=args.seed)
    t_render = time.perf_counter() - t
    t = time.perf_counter()
    views = []
    for v in seq.views:
        rec = reconstruct_pair(v.sim.left, v.sim.right, seq.rig, matcher=args.matcher, mask=v.mask)
        views.append(view_from_reconstruction(v.name, rec, seq.rig, v.sim.left))
    t_rec = time.perf_counter() - t
    truth, truth_ids = sample_leaf_surfaces(seq.scene, spacing=1.0)
    print(f"croton seed {args.seed}, {args.views} views ({args.mode}), 640x480, matcher {args.matcher}; "
          f"render {t_render:.1f} s, reconstruction {t_rec:.1f} s; "
          f"{len(truth)} true leaf-surface samples (1 mm grid)")

    # 1. registration without poses
    t = time.perf_counter()
    settings = RegistrationSettings(voxel=1.5 * args.voxel)
    reg = register_views(views, settings, loop="auto")
    t_reg = time.perf_counter() - t
    T0_true = seq.poses[0]
    rel_true = [invert_transform(T0_true) @ T for T in seq.poses]
    print(f"\nregistration without poses: {t_reg:.1f} s, loop closed: {reg.loop_closed}")
    print(" view   ICP rmse  overlap   error (mm at plant)  error (deg)")
    errs = []
    centre_world = seq.centre
    for i, (Te, Tt) in enumerate(zip(reg.poses, rel_true)):
        c_rig = transform_points(invert_transform(seq.poses[i]), centre_world)
        dt, dr = transform_error(Te, Tt, centre=c_rig)
        errs.append((dt, dr))
        pr = next((p for p in reg.pairs if p.source == i and p.target == i - 1), None)
        rm = f"{pr.icp.rmse:8.2f}  {pr.icp.overlap:6.0%}" if pr else "       -       -"
        print(f"  {i:2d}  {rm}   {dt:10.2f}          {dr:8.3f}")
    e = np.array(errs[1:])
    print(f"  mean over views 1..{len(views) - 1}: {e[:, 0].mean():.2f} mm, {e[:, 1].mean():.3f} deg; "
          f"max {e[:, 0].max():.2f} mm, {e[:, 1].max():.3f} deg")

    # 2. coverage
    print(f"\ncoverage of the true leaf surface within {args.radius:g} mm (accuracy: model points within "
          "10 mm of a leaf, distance to the nearest true sample)")
    single = []
    for v, T in zip(views, seq.poses):
        rep = evaluate_model(v.world_points(T), truth, args.radius, max_distance=10.0)
        single.append(rep)
        print(f"  single {v.name}: {rep.coverage:6.1%}   median {rep.median_error:.2f} mm, "
              f"p90 {rep.p90_error:.2f} mm")
    registered_world = [T0_true @ T for T in reg.poses]
    fused_models = {}
    for label, poses in (("true poses", seq.poses), ("registered poses", registered_world)):
        t = time.perf_counter()
        fused = fuse_views(views, poses, voxel=args.voxel)
        t_fuse = time.perf_counter() - t
        rep = evaluate_model(fused.points, truth, args.radius, max_distance=10.0)
        fused_models[label] = fused
        hist = np.bincount(fused.view_count, minlength=len(views) + 1)[1:]
        print(f"  fused, {label}: {rep.coverage:6.1%}   median {rep.median_error:.2f} mm, p90 "
              f"{rep.p90_error:.2f} mm; {len(fused)} points, {fused.removed_free_space} seen-through "
              f"removed, {t_fuse:.1f} s; views per point 1..{len(views)}: {' '.join(map(str, hist))}")
    best = max(single, key=lambda r: r.coverage)
    fused_cov = evaluate_model(fused_models["true poses"].points, truth, args.radius).coverage
    print(f"  best single view {best.coverage:.1%} -> fused (true poses) {fused_cov:.1%}")

    # 3. leaf measurements
    print("\nmarked leaves (length x width, mm): truth, fused model (registered poses), view 0 alone")
    tree = cKDTree(truth)
    for lf in seq.scene.truth()["leaves"]:
        if not lf["marked"]:
            continue
        row = f"  leaf {lf['id']}: truth {lf['length']:.1f} x {lf['width']:.1f}"
        own = truth[truth_ids == lf["id"]]
        own_tree = cKDTree(own)
        normal = np.asarray(lf["pose"]["axes"])[2]
        for label, pts in (("fused", fused_models["registered poses"].points),
                           ("view 0", views[0].world_points(seq.poses[0]))):
            d_own, nearest = own_tree.query(pts)
            d_all, _ = tree.query(pts)
            off = pts - own[nearest]
            along = off @ normal
            across = np.linalg.norm(off - along[:, None] * normal, axis=1)
            sel = pts[(np.abs(along) < 6.0) & (across < 1.5) & (d_own <= d_all + 1e-9)]
            if len(sel) < 50:
                row += f"; {label}: too few points ({len(sel)})"
                continue
            try:
                L, W = measure_on_points(sel, lf)
                row += (f"; {label} {L:.1f} x {W:.1f} ({100 * (L / lf['length'] - 1):+.1f} %, "
                        f"{100 * (W / lf['width'] - 1):+.1f} %)")
            except Exception as exc:  # noqa: BLE001 - a benchmark row, not a test
                row += f"; {label}: {exc}"
        print(row)


if __name__ == "__main__":
    main()
