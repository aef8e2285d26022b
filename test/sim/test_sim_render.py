"""Ray-cast rendering: exact per-pixel geometry, photometric agreement, anti-aliasing,
lens distortion, units, sensor effects and determinism."""
from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter

from canopy_stereo.geometry.camera import point_depth, project
from canopy_stereo.geometry.distortion import distort_pixels
from canopy_stereo.sim import (
    CLEAN,
    CameraEffects,
    Leaf,
    Rectangle,
    render_pair,
    render_scene,
    render_view,
    rig_at_resolution,
    sample_pattern,
    scene_for_rig,
    visible_from,
)
from canopy_stereo.sim import leaf as leafgeom
from canopy_stereo.sim.primitives import LABEL_BACKGROUND, LABEL_LEAF


@pytest.fixture(scope="module")
def clean_croton(paper_rig):
    return render_scene("croton", paper_rig, seed=0, effects=CLEAN)


def pixel_grid(shape):
    vv, uu = np.mgrid[0:shape[0], 0:shape[1]]
    return np.stack([uu, vv], axis=-1).astype(np.float64)


def interior(key):
    """Pixels whose 3x3 neighbourhood shows the same surface (no edge, no anti-aliased mix)."""
    return (minimum_filter(key, 3) == key) & (maximum_filter(key, 3) == key)


def test_points_project_to_their_pixel_centres(clean_croton):
    sim = clean_croton
    for xyz, P in ((sim.xyz_left, sim.rig.P_left), (sim.xyz_right, sim.rig.P_right)):
        ok = np.all(np.isfinite(xyz), axis=2)
        assert ok.mean() > 0.99  # the background plane fills every view
        err = np.linalg.norm(project(P, xyz[ok]) - pixel_grid(xyz.shape)[ok], axis=1)
        assert err.max() < 0.05
        assert np.all(point_depth(P, xyz[ok]) > 0)


def test_points_lie_on_the_surfaces_they_are_labelled_with(clean_croton):
    sim = clean_croton
    scene = sim.scene
    for lf in scene.leaves:
        m = sim.leaf_ids_left == lf.leaf_id
        if not m.any():
            continue
        local = (sim.xyz_left[m] - lf.base) @ lf.axes.T
        z = leafgeom.surface_height(local[:, 0], local[:, 1], lf.droop, lf.rise, lf.cup)
        assert np.abs(local[:, 2] - z).max() < 1e-6
        hw = leafgeom.half_width_at(local[:, 0] / lf.span, lf.half_width, lf.base_exponent,
                                    lf.tip_exponent)
        assert np.all(np.abs(local[:, 1]) <= hw + 1e-6)
    bg = sim.labels_left == LABEL_BACKGROUND
    dist = (sim.xyz_left[bg] - scene.anchor_origin) @ scene.anchor_axes[2]
    assert np.allclose(dist, scene.background_distance, atol=1e-6)
    assert scene.background_distance == pytest.approx(1000.0)
    assert np.array_equal(sim.labels_left == LABEL_LEAF, sim.leaf_ids_left > 0)


def test_left_and_right_colours_agree_where_both_see_a_point(clean_croton):
    sim = clean_croton
    H, W = sim.left.shape[:2]
    key_l = sim.leaf_ids_left.astype(np.int64) * 16 + sim.labels_left
    key_r = sim.leaf_ids_right.astype(np.int64) * 16 + sim.labels_right
    ok = interior(key_l) & np.all(np.isfinite(sim.xyz_left), axis=2)
    ok[::2] = False  # every other row is plenty
    vv, uu = np.nonzero(ok)
    X = sim.xyz_left[vv, uu]
    uv = project(sim.rig.P_right, X)
    keep = (uv[:, 0] > 2) & (uv[:, 0] < W - 3) & (uv[:, 1] > 2) & (uv[:, 1] < H - 3)
    keep[keep] = visible_from(sim.scene, sim.rig.P_right, X[keep])
    ri = np.rint(uv[keep]).astype(int)
    key_at = key_r[ri[:, 1], ri[:, 0]]
    same = interior(key_r)[ri[:, 1], ri[:, 0]] & (key_at == key_l[vv[keep], uu[keep]])
    keep[keep] = same
    assert keep.sum() > 100_000
    left = sim.left[vv[keep], uu[keep]].astype(np.float64)
    right = sim.right.astype(np.float64)

    def sample_right(x, y):
        x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
        fx, fy = (x - x0)[:, None], (y - y0)[:, None]
        return (right[y0, x0] * (1 - fx) * (1 - fy) + right[y0, x0 + 1] * fx * (1 - fy)
                + right[y0 + 1, x0] * (1 - fx) * fy + right[y0 + 1, x0 + 1] * fx * fy)

    diff = sample_right(uv[keep, 0], uv[keep, 1]) - left
    assert abs(diff.mean()) < 0.5  # no brightness bias between the views
    assert np.median(np.abs(diff)) < 2.5
    assert np.percentile(np.abs(diff), 90) < 8.0
    # the texture is rich: one pixel off, the colours disagree much more
    shifted = sample_right(uv[keep, 0] + 1.0, uv[keep, 1]) - left
    assert np.median(np.abs(shifted)) > 2.5 * np.median(np.abs(diff))


def test_supersampling_is_the_mean_of_shifted_single_samples(paper_rig):
    rig = rig_at_resolution(paper_rig, 0.25)
    scene = scene_for_rig("croton", rig)
    aa = render_view(scene, rig.P_left, None, rig.image_size, supersample=2)
    offsets, weights = sample_pattern(2)
    mean = np.zeros_like(aa.radiance, dtype=np.float64)
    for (du, dv), w in zip(offsets, weights):
        T = np.array([[1, 0, -du], [0, 1, -dv], [0, 0, 1.0]])
        single = render_view(scene, T @ rig.P_left, None, rig.image_size, supersample=1)
        mean += w * single.radiance
    assert np.allclose(aa.radiance, mean, atol=1e-5)
    # the centre sample gives the geometry
    centre = render_view(scene, rig.P_left, None, rig.image_size, supersample=1)
    assert np.array_equal(aa.prim_index, centre.prim_index)
    assert np.allclose(aa.xyz, centre.xyz, equal_nan=True)
    # edges get intermediate values: more distinct radiance levels than single samples
    edge = aa.prim_index != np.roll(aa.prim_index, 1, axis=1)
    assert np.abs(aa.radiance - centre.radiance)[edge].max() > 0.05


def test_distorted_rig_points_project_through_the_lens_model(paper_rig):
    rig = replace(rig_at_resolution(paper_rig, 0.5), D_left=[-0.28, 0.09, 0.0012, -0.0008, -0.01],
                  D_right=[-0.22, 0.05, -0.0005, 0.001, 0.0])
    sim = render_pair(scene_for_rig("croton", rig), rig, supersample=1, effects=CLEAN)
    for xyz, P, D in ((sim.xyz_left, rig.P_left, rig.D_left),
                      (sim.xyz_right, rig.P_right, rig.D_right)):
        ok = np.all(np.isfinite(xyz), axis=2)
        assert ok.mean() > 0.99
        uv = distort_pixels(P, D, project(P, xyz[ok]))
        assert np.abs(uv - pixel_grid(xyz.shape)[ok]).max() < 0.05
    # barrel distortion: a distorted image sees more of the world than the pinhole one
    pinhole = render_pair(scene_for_rig("croton", rig), replace(rig, D_left=np.zeros(5),
                                                                   D_right=np.zeros(5)),
                          supersample=1, effects=CLEAN)
    span = lambda xyz: np.nanmax(xyz[..., 0]) - np.nanmin(xyz[..., 0])  # noqa: E731
    assert span(sim.xyz_left) > span(pinhole.xyz_left)


def test_rig_in_metres_sees_the_same_scene(paper_rig):
    rig_mm = rig_at_resolution(paper_rig, 0.25)
    S = np.diag([1000.0, 1000.0, 1000.0, 1.0])  # metres -> millimetres
    rig_m = replace(rig_mm, P_left=rig_mm.P_left @ S, P_right=rig_mm.P_right @ S, world_unit="m")
    a = render_scene("croton", rig_mm, effects=CLEAN)
    b = render_scene("croton", rig_m, effects=CLEAN)
    assert b.truth["world_unit"] == "m"
    assert np.allclose(b.xyz_left * 1000.0, a.xyz_left, atol=1e-6, equal_nan=True)
    assert np.mean(a.leaf_ids_left == b.leaf_ids_left) > 0.999
    assert np.mean(np.abs(a.left.astype(int) - b.left.astype(int)) > 1) < 0.001
    la, lb = a.truth["leaves"][0], b.truth["leaves"][0]
    assert lb["length"] * 1000 == pytest.approx(la["length"])
    assert lb["area"] * 1e6 == pytest.approx(la["area"])
    assert b.truth["background"]["distance"] * 1000 == pytest.approx(1000.0)


def test_rendering_is_deterministic_and_seeded(paper_rig):
    rig = rig_at_resolution(paper_rig, 0.25)
    a = render_scene("citrus_branch", rig, seed=3)
    b = render_scene("citrus_branch", rig, seed=3)
    c = render_scene("citrus_branch", rig, seed=4)
    for name in ("left", "right", "xyz_left", "xyz_right", "leaf_ids_left", "labels_right"):
        assert np.array_equal(getattr(a, name), getattr(b, name), equal_nan=True), name
    assert a.truth == b.truth
    assert not np.array_equal(a.left, c.left)
    assert a.truth["leaves"] != c.truth["leaves"]


def test_sensor_gain_vignetting_and_noise():
    h, w = 120, 160
    radiance = np.full((h, w, 3), 0.3, np.float32)
    base = CLEAN.expose(radiance, 0, None).astype(float)
    assert np.all(base == np.rint(255 * 0.3 ** (1 / 2.2) * CLEAN.exposure ** (1 / 2.2)))
    dim = replace(CLEAN, gain_right=0.8).expose(radiance, 1, None).astype(float)
    assert np.allclose(dim / base, 0.8 ** (1 / 2.2), atol=0.01)
    vig = replace(CLEAN, vignetting=0.3).expose(radiance, 0, None).astype(float)
    assert vig[0, 0, 0] / base[0, 0, 0] == pytest.approx(0.7 ** (1 / 2.2), abs=0.01)
    assert vig[h // 2, w // 2, 0] == pytest.approx(base[h // 2, w // 2, 0], abs=1)
    noisy = replace(CLEAN, noise_sigma=3.0).expose(radiance, 0, np.random.default_rng(1))
    assert np.std(noisy.astype(float) - base) == pytest.approx(3.0, rel=0.05)
    with pytest.raises(ValueError):
        CameraEffects(vignetting=1.5)


@pytest.mark.slow
def test_sensor_effects_on_a_rendered_pair(clean_croton, paper_rig):
    effects = replace(CLEAN, gain_right=0.9, noise_sigma=1.0)
    sim = render_pair(clean_croton.scene, paper_rig, effects=effects)
    assert np.std(sim.left.astype(float) - clean_croton.left) == pytest.approx(1.0, abs=0.1)
    ratio = sim.right.astype(float).mean() / clean_croton.right.astype(float).mean()
    assert ratio == pytest.approx(0.9 ** (1 / 2.2), abs=0.01)
    # the default sensors differ between the cameras (gain) and vignette
    default = render_pair(clean_croton.scene, paper_rig)
    assert default.right.mean() < default.left.mean() - 2
    corner, centre = np.s_[:40, :40], np.s_[220:260, 300:340]

    def ratio(region):
        return default.left[region].mean() / clean_croton.left[region].mean()

    assert ratio(corner) < ratio(centre) - 0.03


def test_visibility_of_points_behind_a_leaf(clean_croton):
    sim = clean_croton
    leaf: Leaf = sim.scene.leaf(1)
    P = sim.rig.P_left
    on_leaf = leaf.surface_points(10, 5)
    assert visible_from(sim.scene, P, on_leaf).all()
    C = np.linalg.solve(P[:, :3], -P[:, 3])
    behind = on_leaf + 20.0 * (on_leaf - C) / np.linalg.norm(on_leaf - C, axis=1, keepdims=True)
    assert not visible_from(sim.scene, P, behind).any()
    assert isinstance(sim.scene.background, Rectangle)
