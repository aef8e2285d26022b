"""Leaf and canopy measurement on analytic scenes with exact answers."""
from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.camera import camera_centre
from canopy_stereo.measure import (
    canopy_dimensions,
    estimate_camera,
    hull_volume,
    load_cloud,
    measure_leaf,
    measure_organized,
    measure_points,
    measure_scene,
    plot_views,
    separate_leaves,
    voxel_volume,
    write_report,
)
from canopy_stereo.measure.analytic import Plane, render
from canopy_stereo.measure.canopy import nice_voxel_size
from canopy_stereo.measure.frame import MeasuringFrame, ransac_plane
from canopy_stereo.measure.sections import outline_field
from canopy_stereo.measure.surface import local_linear_fit
from test.support.scenes import leaf_in_view, two_leaf_scene


def _errors(m, leaf):
    return (m.length / leaf.length - 1, m.width / leaf.width - 1, m.area / leaf.area - 1)


@pytest.fixture(scope="module")
def rig():
    from pathlib import Path

    from canopy_stereo.io.rig import load_rig

    return load_rig(Path(__file__).resolve().parents[2] / "config" / "paper_rig.yaml")


@pytest.mark.parametrize("pixel,dist,theta,normal", [
    ((320, 240), 380.0, 10.0, [0.1, -0.2, -1.0]),
    ((300, 250), 400.0, 55.0, [-0.3, 0.2, -1.0]),
    ((340, 230), 360.0, -30.0, [0.3, 0.3, -1.0]),
])
def test_flat_elliptic_leaf_within_half_percent(rig, pixel, dist, theta, normal):
    leaf = leaf_in_view(rig.P_left, pixel, dist, theta, normal)
    org, lab = render(rig.P_left, rig.image_size, [leaf, Plane(camera_centre(rig.P_left) + [0, 0, 900],
                                                                [0, 0, 1])])
    m = measure_leaf(org, lab == 1)
    assert m.extra["surface_model"] == "exact"
    for err in _errors(m, leaf):
        assert abs(err) < 0.005
    # a flat leaf: the plane fits exactly and its normal faces the camera
    e1, e2, n = leaf.frame()
    assert abs(abs(m.normal @ n) - 1) < 1e-6
    assert m.normal @ (camera_centre(rig.P_left) - m.centroid) > 0
    assert m.plane_rms < 1e-4
    assert np.linalg.norm(m.centroid - leaf.centre) < 0.5
    assert m.complete and not m.touches_border and m.extra["reliable"]
    # the length runs along the major axis, the width across it
    assert abs(abs((m.ends[1] - m.ends[0]) @ e1) / m.chord - 1) < 1e-3


@pytest.mark.parametrize("bend,radius,sign", [("length", 150.0, -1.0), ("width", 120.0, 1.0),
                                              ("length", 200.0, 1.0)])
@pytest.mark.slow
def test_curved_leaf_lengths_follow_the_surface(rig, bend, radius, sign):
    leaf = leaf_in_view(rig.P_left, (320, 240), 380.0, 20.0, [0.1, -0.3, -1.0], radius=radius, bend=bend,
                 bend_sign=sign)
    org, lab = render(rig.P_left, rig.image_size, [leaf])
    m = measure_leaf(org, lab == 1)
    for err in _errors(m, leaf):
        assert abs(err) < 0.005
    # along a curved direction the surface length clearly exceeds the chord
    if bend == "length":
        assert m.length > m.chord * 1.01


def test_noisy_leaf_rays_model_averages_matching_noise(rig):
    """1 mm depth noise per pixel along the rays (a stereo reconstruction's error)."""
    P = rig.P_left
    C = camera_centre(P)
    leaf = leaf_in_view(P, (300, 250), 400.0, 55.0, [-0.3, 0.2, -1.0])
    org, lab = render(P, rig.image_size, [leaf, Plane(C + [0, 0, 900], [0, 0, 1])])
    dist = np.linalg.norm(org - C, axis=-1)
    noise = np.random.default_rng(3).normal(scale=1.0, size=dist.shape)
    noisy = C + (org - C) * ((dist + noise) / dist)[..., None]
    m = measure_leaf(noisy, lab == 1, camera=P)
    assert m.extra["surface_model"] == "rays"
    for err in _errors(m, leaf):
        assert abs(err) < 0.005
    # the raw noisy grid would add area: the plain pixel footprints overestimate it
    from canopy_stereo.measure.surface import pixel_footprints

    raw_area = np.nansum(pixel_footprints(np.where((lab == 1)[..., None], noisy, np.nan)))
    assert raw_area > 1.5 * leaf.area


def test_rim_outliers_do_not_change_the_leaf(rig):
    """Background depths bled onto the rim (as block matchers do) are dropped."""
    P = rig.P_left
    C = camera_centre(P)
    leaf = leaf_in_view(P, (320, 240), 380.0, 10.0, [0.1, -0.2, -1.0])
    org, lab = render(P, rig.image_size, [leaf])
    import cv2

    m = lab == 1
    rim = m & ~cv2.erode(m.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    bad = org.copy()
    bad[rim] = C + (org[rim] - C) * 1.6  # 60 % farther: the background behind
    res = measure_leaf(bad, m, camera=P)
    assert res.extra["outliers"] >= 0.9 * rim.sum()
    for err in _errors(res, leaf):
        assert abs(err) < 0.01


def test_estimate_camera_recovers_left_camera(rig):
    P = rig.P_left
    C = camera_centre(P)
    leaf = leaf_in_view(P, (320, 240), 380.0, 10.0, [0.1, -0.2, -1.0])
    org, _ = render(P, rig.image_size, [leaf, Plane(C + [0, 0, 900], [0.1, 0, 1])])
    est = estimate_camera(org)
    assert est is not None
    assert np.linalg.norm(camera_centre(est) - C) < 1e-3
    # a single plane cannot determine a camera
    flat, _ = render(P, rig.image_size, [Plane(C + [0, 0, 900], [0.1, 0, 1])])
    assert estimate_camera(flat) is None


def test_local_linear_fit_reproduces_planes_and_fills_holes():
    h, w = 40, 50
    vv, uu = np.mgrid[0:h, 0:w].astype(float)
    pts = np.stack([2.0 * uu + 0.5 * vv, -vv, 0.3 * uu + 7.0], axis=-1)
    valid = np.ones((h, w), bool)
    valid[15:25, 20:30] = False  # a hole
    X, Xu, Xv = local_linear_fit(pts, valid, np.ones((h, w), bool), sigma=2.0)
    assert np.allclose(X, pts, atol=1e-9)
    assert np.allclose(Xu, [2.0, 0.0, 0.3], atol=1e-9)
    assert np.allclose(Xv, [0.5, -1.0, 0.0], atol=1e-9)


def test_outline_field_crosses_zero_half_way():
    m = np.zeros((20, 20), bool)
    m[5:15, 5:15] = True
    phi = outline_field(m)
    assert phi[10, 10] > 0.45 and phi[10, 0] < -0.45
    # straight edge: symmetric about the mid-point between pixels 14 and 15
    assert abs(phi[10, 14] + phi[10, 15]) < 1e-9


def test_hull_and_voxel_volumes_of_a_box():
    g = np.linspace(0.0, 1.0, 11)
    x, y, z = np.meshgrid(g * 40.0, g * 20.0, g * 10.0, indexing="ij")
    pts = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    assert abs(hull_volume(pts) - 8000.0) < 1e-6
    vol, n = voxel_volume(pts, 4.0)
    assert n == len(np.unique(np.floor(pts / 4.0), axis=0))
    assert vol == pytest.approx(n * 64.0)
    assert hull_volume(pts[:3]) == 0.0
    assert nice_voxel_size(523.0) == 10.0 and nice_voxel_size(0.9) == 0.02
    with pytest.raises(CanopyStereoError, match="voxel size"):
        voxel_volume(pts, 0.0)


def test_ransac_plane_finds_the_floor_among_clutter(rng):
    floor = np.column_stack([rng.uniform(-100, 100, 3000), np.full(3000, 50.0) + rng.normal(0, 0.2, 3000),
                             rng.uniform(300, 500, 3000)])
    clutter = rng.uniform([-100, -100, 300], [100, 40, 500], size=(1500, 3))
    n, d, inl = ransac_plane(np.vstack([floor, clutter]), threshold=1.0)
    assert abs(abs(n[1]) - 1.0) < 1e-3
    assert abs(abs(d) - 50.0) < 0.5
    assert inl[:3000].mean() > 0.99 and inl[3000:].mean() < 0.05


def test_canopy_dimensions_in_a_given_frame():
    pts = np.array([[0, 0, 0], [30, 0, 0], [0, 20, 0], [0, 0, 10], [30, 20, 10]], float)
    frame = MeasuringFrame(np.zeros(3), np.eye(3), "plane", np.array([0, 0, 1.0, 0]))
    d = canopy_dimensions(pts, frame, voxel_size=5.0, leaf_area=600.0)
    assert (d["width"], d["depth"], d["height"]) == (30.0, 20.0, 10.0)
    assert d["top_above_ground"] == 10.0 and d["base_above_ground"] == 0.0
    assert d["leaf_area_density"] == pytest.approx(600.0 / d["hull_volume"])
    with pytest.raises(CanopyStereoError, match="at least 3"):
        canopy_dimensions(pts[:2], frame)


def test_measure_organized_report_with_leaf_ids(rig, tmp_path):
    org, lab, leaves = two_leaf_scene(rig)
    ids = np.where(lab == 1, 7, np.where(lab == 2, 9, 0))
    report = measure_organized(org, leaf_ids=ids, ground="auto", unit="mm")
    assert report["unit"] == "mm" and report["units"]["volume"] == "mm^3"
    assert [lf["id"] for lf in report["leaves"]] == [7, 9]
    for lf, truth in zip(report["leaves"], leaves):
        assert abs(lf["length"] / truth.length - 1) < 0.005
        assert abs(lf["width"] / truth.width - 1) < 0.005
        assert abs(lf["area"] / truth.area - 1) < 0.005
        assert len(lf["normal"]) == 3 and abs(np.linalg.norm(lf["normal"]) - 1) < 1e-5
    # the floor was found: up is -y (image up), and both leaves stand above it
    frame = report["frame"]
    assert frame["kind"] == "ground"
    assert np.dot(frame["z_axis"], [0, -1, 0]) > 0.999
    pts = org[(lab == 1) | (lab == 2)]
    height = np.ptp(pts @ np.asarray(frame["z_axis"]))
    canopy = report["canopy"]
    assert canopy["height"] == pytest.approx(height, rel=1e-6)
    assert canopy["top_above_ground"] == pytest.approx(np.max(pts @ np.asarray(frame["z_axis"]))
                                                        + frame["ground_plane"][3], rel=1e-6)
    assert canopy["leaf_area"] == pytest.approx(sum(lf["area"] for lf in report["leaves"]))
    # volumes of the two leaves' points: scipy's convex hull, the occupied voxels counted here
    from scipy.spatial import ConvexHull

    assert canopy["n_points"] == len(pts)
    assert canopy["hull_volume"] == pytest.approx(ConvexHull(pts).volume, rel=1e-9)
    vs = canopy["voxel_size"]
    occupied = len(np.unique(np.floor(pts / vs).astype(np.int64), axis=0))  # the world-frame grid
    assert canopy["occupied_voxels"] == occupied and canopy["voxel_volume"] == pytest.approx(occupied * vs ** 3)
    assert canopy["leaf_area_density"] == pytest.approx(canopy["leaf_area"] / canopy["hull_volume"])
    # JSON and CSV
    out = write_report(report, tmp_path / "r.json", csv=tmp_path / "leaves.csv")
    again = json.loads(out.read_text())
    assert again["leaves"][0]["id"] == 7
    # written in the one unit set: lengths mm, areas cm^2, volumes cm^3 (the cloud is in mm)
    assert again["units"] == {"length": "mm", "area": "cm^2", "volume": "cm^3", "leaf_area_density": "1/cm"}
    assert again["leaves"][0]["length"] == pytest.approx(report["leaves"][0]["length"])
    assert again["leaves"][0]["area"] == pytest.approx(report["leaves"][0]["area"] / 100.0)
    assert again["canopy"]["hull_volume"] == pytest.approx(canopy["hull_volume"] / 1000.0)
    assert again["canopy"]["voxel_size"] == pytest.approx(vs)
    rows = list(csv.reader(open(tmp_path / "leaves.csv", encoding="utf-8")))
    assert rows[0][:5] == ["id", "length_mm", "width_mm", "area_cm2", "chord_mm"] and len(rows) == 3
    assert float(rows[1][3]) == pytest.approx(report["leaves"][0]["area"] / 100.0, abs=1e-4)


@pytest.mark.slow
def test_measure_with_plant_mask_separates_leaves(rig, tmp_path):
    org, lab, leaves = two_leaf_scene(rig)
    res = measure_scene(org, mask=(lab == 1) | (lab == 2), ground="camera")
    assert len(res.report["leaves"]) == 2
    lengths = sorted(lf["length"] for lf in res.report["leaves"])
    assert lengths == pytest.approx(sorted(lf.length for lf in leaves), rel=0.01)
    assert res.report["frame"]["kind"] == "camera"
    png = plot_views(res, tmp_path / "views.png", title="two leaves")
    assert png.stat().st_size > 10000


def test_separate_leaves_cuts_depth_jumps_and_creases(rig):
    P = rig.P_left
    # a leaf partly in front of another (depth jump) and a folded pair (crease)
    front = leaf_in_view(P, (250, 240), 380.0, 0.0, [0.0, 0.0, -1.0], a=60.0, b=40.0)
    back = leaf_in_view(P, (330, 240), 460.0, 0.0, [0.0, 0.0, -1.0], a=70.0, b=45.0)
    org, lab = render(P, rig.image_size, [front, back])
    ids = separate_leaves(org, lab > 0)
    assert ids.max() == 2
    for k in (1, 2):
        truth = lab == k
        best = max(((ids == j) & truth).sum() / ((ids == j) | truth).sum() for j in (1, 2))
        assert best > 0.95
    # no pixel of one leaf is given to the other (thin horns may stay unlabelled)
    assert len(np.unique(ids[lab == 1])) <= 2 and len(np.unique(ids[lab == 2])) <= 2
    assert set(np.unique(ids[lab == 1])) - {0} != set(np.unique(ids[lab == 2])) - {0}
    # crease: two half-planes meeting at 90 degrees along a line, no depth jump
    vv, uu = np.mgrid[0:120, 0:160].astype(float)
    x = (uu - 80.0)
    crease = np.stack([x, vv, 300.0 + np.abs(x)], axis=-1)
    ids2 = separate_leaves(crease, np.ones(uu.shape, bool), min_pixels=100)
    left, right = ids2[:, :70], ids2[:, 90:]
    assert ids2.max() == 2 and len(np.unique(left)) == 1 and len(np.unique(right)) == 1
    assert left[0, 0] != right[0, 0]


def test_measure_points_from_ply(rig, tmp_path):
    from canopy_stereo.io.ply import write_ply

    org, lab, _ = two_leaf_scene(rig)
    pts = org[(lab >= 1) & (lab <= 3)]  # the leaves and the floor they stand on
    write_ply(tmp_path / "c.ply", pts, unit="mm")
    cloud, unit = load_cloud(tmp_path / "c.ply")
    assert unit == "mm" and cloud.shape == pts.shape
    res = measure_points(cloud)
    assert res.report["frame"]["kind"] == "ground"
    plant = org[(lab == 1) | (lab == 2)]
    z = np.asarray(res.report["frame"]["z_axis"])
    assert res.report["canopy"]["height"] == pytest.approx(np.ptp(plant @ z), rel=0.02)
    assert res.report["leaves"] == []


# ------------------------------------------------------------------ bad input


def test_bad_inputs_give_clear_messages(rig, tmp_path):
    org, lab, _ = two_leaf_scene(rig)
    with pytest.raises(CanopyStereoError, match="mask is empty"):
        measure_organized(org, mask=np.zeros(lab.shape, bool))
    with pytest.raises(CanopyStereoError, match=r"leaf 1: the mask is empty"):
        measure_leaf(org, np.zeros(lab.shape, bool))
    with pytest.raises(CanopyStereoError, match=r"mask is 320x240 but the organized cloud is 640x480"):
        measure_organized(org, mask=np.ones((240, 320), bool))
    with pytest.raises(CanopyStereoError, match=r"leaf-id image is 100x100"):
        measure_organized(org, leaf_ids=np.ones((100, 100), np.uint8))
    few = np.full_like(org, np.nan)
    few[0, 0] = few[0, 1] = [1.0, 2.0, 3.0]
    with pytest.raises(CanopyStereoError, match="2 valid 3D points; need at least 3"):
        measure_organized(few)
    with pytest.raises(CanopyStereoError, match="only 2 of its 2 pixels have a 3D point"):
        m = np.zeros(lab.shape, bool)
        m[0, :2] = True
        measure_leaf(few, m)
    with pytest.raises(CanopyStereoError, match="need at least 3 to measure"):
        measure_points(np.zeros((2, 3)))
    with pytest.raises(CanopyStereoError, match=r"must be an \(H, W, 3\) array"):
        measure_organized(np.zeros((10, 3)))
    with pytest.raises(CanopyStereoError, match="ground must be"):
        measure_organized(org, ground="sideways")
    # files
    notply = tmp_path / "cloud.ply"
    notply.write_text("this is not a point cloud\n")
    with pytest.raises(CanopyStereoError, match="is not a PLY file"):
        load_cloud(notply)
    other = tmp_path / "cloud.xyz"
    other.write_text("1 2 3\n")
    with pytest.raises(CanopyStereoError, match="unsupported cloud file"):
        load_cloud(other)
    with pytest.raises(CanopyStereoError, match="not found"):
        load_cloud(tmp_path / "missing.npy")
    np.save(tmp_path / "flat.npy", np.zeros((4, 5)))
    with pytest.raises(CanopyStereoError, match=r"shape \(H, W, 3\)"):
        load_cloud(tmp_path / "flat.npy")


# ------------------------------------------------------------------ cleaning (the CLI: test/cli/test_measure.py)


def test_detached_clusters_are_dropped_attached_ones_kept():
    from canopy_stereo.measure.cleaning import drop_detached_clusters

    rng = np.random.default_rng(3)
    canopy = rng.uniform(0, 300, size=(20000, 3))            # the canopy: a 300 mm block
    sliver = rng.normal([300, 150, 600], 2.0, size=(30, 3))  # stray matches 300 mm behind it
    tip = rng.normal([150, 150, 305], 1.0, size=(30, 3))     # a small tip touching the canopy
    P = np.concatenate([canopy, sliver, tip])
    keep = drop_detached_clusters(P, cell=12.0, min_fraction=0.002)
    assert keep[:20000].all() and not keep[20000:20030].any() and keep[20030:].all()
    # only candidates may go
    cand = np.zeros(len(P), bool)
    assert drop_detached_clusters(P, cell=12.0, min_fraction=0.002, candidates=cand).all()


def test_summary_names_a_leaf_without_width_instead_of_printing_0_mm():
    """A 'leaf' whose midrib was not found (a cluster of leaves) has width 0 in the report;
    the summary says it was not measured rather than '0 mm'."""
    from canopy_stereo.measure.plant import measurement_lines

    canopy = {"height": 300.0, "width": 200.0, "depth": 150.0, "hull_volume": 900.0, "voxel_volume": 100.0,
              "voxel_size": 10.0, "n_leaves": 2}
    leaves = [{"id": 1, "length": 120.0, "width": 45.0, "area": 40.0},
              {"id": 2, "length": 133.0, "width": 0.0, "area": 66.0}]
    lines = measurement_lines({"canopy": canopy, "leaves": leaves, "source": {"mask": "auto"},
                               "reference": {"kind": "ground"}})
    assert "  leaf 1: length 120 mm, width 45 mm, area 40.0 cm^2" in lines
    assert "  leaf 2: length 133 mm, width not measured (no single midrib), area 66.0 cm^2" in lines
