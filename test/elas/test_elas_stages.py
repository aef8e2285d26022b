"""Per-stage unit tests of the ELAS implementation (canopy_stereo.elas)."""
from __future__ import annotations

import numpy as np
import pytest

from canopy_stereo.elas import delaunay, descriptor, grid, matching, postprocess, support
from canopy_stereo.elas.params import make_params
from canopy_stereo.elas.simd import sad16, sad64, sad_reference
from canopy_stereo.sim.stereo_pair import shifted_pair


# ---------------------------------------------------------------- descriptor
def test_sad_intrinsics_match_a_plain_loop(rng):
    from numba import njit

    @njit
    def both(a, b, n):
        out = np.zeros((n, 2), np.int64)
        for i in range(n):
            out[i, 0] = sad16(a, i * 16, b, (n - 1 - i) * 16 + 3)
            out[i, 1] = sad_reference(a, i * 16, b, (n - 1 - i) * 16 + 3, 16)
        return out

    @njit
    def both64(a, b, n):
        out = np.zeros((n, 2), np.int64)
        for i in range(n):
            out[i, 0] = sad64(a, i * 16, b, (n - 1 - i) * 16 + 5)
            out[i, 1] = sad_reference(a, i * 16, b, (n - 1 - i) * 16 + 5, 64)
        return out

    a = rng.integers(0, 256, 16 * 200, dtype=np.uint8)
    b = rng.integers(0, 256, 16 * 200 + 3, dtype=np.uint8)
    out = both(a, b, 200)
    assert np.array_equal(out[:, 0], out[:, 1])
    a = rng.integers(0, 256, 16 * 203, dtype=np.uint8)
    b = rng.integers(0, 256, 16 * 203 + 5, dtype=np.uint8)
    out = both64(a, b, 200)
    assert np.array_equal(out[:, 0], out[:, 1])

    @njit
    def one(a, b):
        return sad16(a, 0, b, 0)

    # extremes: 16 * 255 does not overflow
    assert one(np.zeros(16, np.uint8), np.full(16, 255, np.uint8)) == 16 * 255
    assert one(np.full(16, 255, np.uint8), np.zeros(16, np.uint8)) == 16 * 255


def test_gradient_bytes_of_a_ramp():
    # I = 4u: Sobel left-minus-right = 4 * (4(u-1) - 4(u+1)) = -32 -> (-32 >> 2) + 128 = 120
    img = np.tile((4 * np.arange(40)).astype(np.uint8), (30, 1))
    du, dv = descriptor.gradient_bytes(img)
    assert np.all(du[1:-1, 1:-1] == 120)
    assert np.all(dv[1:-1, 1:-1] == 128)
    # vertical ramp I = 4v: top-minus-bottom = -32 -> 120
    du, dv = descriptor.gradient_bytes(np.ascontiguousarray(img.T))
    assert np.all(dv[1:-1, 1:-1] == 120)
    assert np.all(du[1:-1, 1:-1] == 128)


def test_descriptor_bytes_on_an_impulse():
    # one bright pixel at (u0, v0) = (10, 9) on black
    img = np.zeros((20, 22), np.uint8)
    u0, v0 = 10, 9
    img[v0, u0] = 255
    desc, texture = descriptor.compute_descriptors(img)
    assert desc.shape == (20, 22, 16) and desc.dtype == np.uint8
    # du at (v0, u0-1): left - right = -2*255 = -510 -> floor(-510/4) = -128 -> 0
    # du at (v0, u0+1): +510 -> 127 + 128 = 255; (v0+-1, u0-+1): -+255 -> 64 / 191
    d = desc[v0, u0]
    # du samples: (-2,0) (-1,-2) (-1,0) (-1,2) (0,-1) (0,0) (0,0) (0,1) (1,-2) (1,0) (1,2) (2,0)
    assert list(d[:12]) == [128, 128, 128, 128, 0, 128, 128, 255, 128, 128, 128, 128]
    # dv samples (top - bottom): (-1,0) -> pixel is below: -510 -> 0; (1,0) -> 255; (0,+-1) -> 128
    assert list(d[12:]) == [0, 128, 128, 255]
    assert texture[v0, u0] == 128 * 2 + 127 * 2
    # the pixel below-left, (u0-1, v0+1): du (-1,0) is du(v0, u0-1) = 0, du (-1,2) is
    # du(v0, u0+1) = 255, du (0,0) is du(v0+1, u0-1) = (-255 >> 2) + 128 = 64, du (0,1) is
    # du(v0+1, u0) = 128 (the bright column is its centre column)
    d = desc[v0 + 1, u0 - 1]
    assert (d[2], d[3], d[5], d[6], d[7]) == (0, 255, 64, 64, 128)
    # border: zeros within 3 px of the edge
    assert not desc[:3].any() and not desc[-3:].any()
    assert not desc[:, :3].any() and not desc[:, -3:].any()
    assert texture[:3].sum() == 0 and texture[:, -3:].sum() == 0


def test_descriptor_word_and_byte_assembly_agree(rng):
    img = rng.integers(0, 256, (25, 37), dtype=np.uint8)
    du, dv = descriptor.gradient_bytes(img)
    by_bytes = descriptor._assemble_bytes(du, dv, descriptor._DU_DR, descriptor._DU_DC,
                                          descriptor._DV_DR, descriptor._DV_DC)
    by_words, texture_words = descriptor._assemble_words(du, dv)
    assert np.array_equal(by_bytes, by_words)
    assert np.array_equal(texture_words, descriptor._texture(by_bytes))
    assert texture_words.dtype == np.int32
    # against a direct transcription of the offset tables
    desc, texture = descriptor.compute_descriptors(img)
    v, u = 12, 20
    expect = [du[v + r, u + c] for r, c in descriptor.DU_OFFSETS] + \
             [dv[v + r, u + c] for r, c in descriptor.DV_OFFSETS]
    assert list(desc[v, u]) == expect
    assert texture[v, u] == int(np.abs(np.asarray(expect, int) - 128).sum())


def test_tiny_image_descriptor_is_zero():
    desc, texture = descriptor.compute_descriptors(np.full((5, 5), 7, np.uint8))
    assert desc.shape == (5, 5, 16) and not desc.any() and not texture.any()


# ------------------------------------------------------------ support points
def test_support_points_of_a_shifted_pair_have_the_shift():
    left, right, _ = shifted_pair(120, 90, shift=9.0, seed=4)
    dl, tl = descriptor.compute_descriptors(left)
    dr, tr = descriptor.compute_descriptors(right)
    pts = support.support_points(dl, dr, tl, tr, make_params("robotics", disp_max=40))
    assert len(pts) >= 20
    assert np.all(pts[:, 2] == 9)
    assert np.all(pts[:, 0] % 5 == 0) and np.all(pts[:, 1] % 5 == 0)
    assert pts[:, 0].min() >= support.SUPPORT_MARGIN and pts[:, 0].max() <= 120 - 1 - 5


def test_support_candidates_need_texture():
    flat = np.full((40, 60), 100, np.uint8)
    dl, tl = descriptor.compute_descriptors(flat)
    grid_ = support.candidate_grid(dl, dl, tl, tl, 5, 0, 20, 10, 0.85, 2)
    assert (grid_ < 0).all()


def test_remove_inconsistent_drops_isolated_disagreeing_points():
    g = np.full((14, 14), -1, np.int32)
    g[2:7, 2:7] = 20           # 25 consistent points
    g[4, 4] = 40               # an outlier inside the block
    g[11, 11] = 22             # within 5 cells it sees only (6, 6): 2 supporters < 5
    g[10, 10] = 24             # sees (5..6, 5..6) (4 points within 5) and (11, 11): kept
    support.remove_inconsistent(g, 5, 5, 5)
    assert g[4, 4] == -1
    assert g[11, 11] == -1
    assert g[10, 10] == 24
    assert (g[2:7, 2:7] >= 0).sum() == 24


def test_remove_redundant_keeps_every_sixth_point_of_a_chain():
    # in place, columns outer / rows inner: in a vertical chain of equal disparities a
    # point is redundant while an earlier kept point is within 5 cells
    g = np.full((20, 3), -1, np.int32)
    g[:, 1] = 7
    support.remove_redundant(g, 5, 1, True)
    assert list(np.flatnonzero(g[:, 1] >= 0)) == [0, 6, 12, 18, 19]
    # the horizontal pass does not touch an isolated column
    support.remove_redundant(g, 5, 1, False)
    assert list(np.flatnonzero(g[:, 1] >= 0)) == [0, 6, 12, 18, 19]
    # a neighbour with |dd| > 1 does not make a point redundant
    g = np.full((3, 1), -1, np.int32)
    g[:, 0] = [5, 7, 5]
    support.remove_redundant(g, 5, 1, True)
    assert list(g[:, 0]) == [5, 7, 5]


def test_corner_points_take_the_nearest_disparity():
    pts = np.array([[10, 10, 3], [90, 10, 8], [10, 70, 5], [90, 70, 12]], np.int32)
    c = support.corner_points(pts, 100, 80)
    assert c.shape == (8, 3)
    assert c[:4].tolist() == [[0, 0, 3], [99, 0, 8], [0, 79, 5], [99, 79, 12]]
    # the right-image corners: u - d lands on the corner column
    assert (c[4:, 0] - c[4:, 2]).tolist() == [0, 99, 0, 99]
    assert len(support.corner_points(np.zeros((0, 3), np.int32), 100, 80)) == 0


# ------------------------------------------------------------ planes, raster
def test_fit_planes_recovers_a_plane_and_zeroes_singular_triangles():
    u = np.array([0, 10, 0, 10, 20, 30], float)
    v = np.array([0, 0, 10, 10, 20, 30], float)
    d = 0.25 * u - 0.5 * v + 7.0
    planes = delaunay.fit_planes(u, v, d, np.array([[0, 1, 2], [1, 3, 2], [0, 3, 5]]))
    assert planes.dtype == np.float32
    np.testing.assert_allclose(planes[0], [0.25, -0.5, 7.0], atol=1e-6)
    np.testing.assert_allclose(planes[1], [0.25, -0.5, 7.0], atol=1e-6)
    assert np.all(planes[2] == 0)  # collinear vertices


def test_triangle_planes_validity_uses_both_images():
    # d = 0.5 u: slope 0.5 in the left image, 0.5 / (1 - 0.5) = 1 in the right one
    pts = np.array([[0, 0, 0], [40, 0, 20], [0, 40, 0], [40, 40, 20]], np.int32)
    _, tri, planes, valid = delaunay.triangle_planes(pts, right_image=False)
    assert len(tri) == 2 and not valid.any()
    np.testing.assert_allclose(planes[:, 0], 0.5, atol=1e-6)
    _, _, planes_r, _ = delaunay.triangle_planes(pts, right_image=True)
    np.testing.assert_allclose(planes_r[:, 0], 1.0, atol=1e-6)
    flat = pts.copy()
    flat[:, 2] = 5
    assert delaunay.triangle_planes(flat, right_image=False)[3].all()


def _circumcircle_is_empty(pts, tri):
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    assert (cross > 0).all()                       # counter-clockwise, non-degenerate
    for k in range(len(tri)):
        e1, e2 = b[k] - a[k], c[k] - a[k]
        centre = np.linalg.solve(np.array([e1, e2]), 0.5 * np.array([e1 @ e1, e2 @ e2]))
        dist2 = ((pts - a[k] - centre) ** 2).sum(axis=1)
        assert (dist2 >= centre @ centre * (1 - 1e-9)).all()
    return 0.5 * cross.sum()


def test_sweep_delaunay_equals_qhull_in_general_position(rng):
    from scipy.spatial import ConvexHull, Delaunay

    for n in (3, 4, 10, 300):
        pts = rng.uniform(0, 500, (n, 2))
        ours = {tuple(sorted(t)) for t in delaunay.triangulate(pts).tolist()}
        ref = {tuple(sorted(t)) for t in Delaunay(pts).simplices.tolist()}
        assert ours == ref
    # support-point-like input: integer grid points (many co-circular quadruples), the
    # right image's (u - d, v) with repeated points; any valid Delaunay triangulation
    grid_pts = np.array([(u, v) for u in range(5, 300, 5) for v in range(5, 200, 5)], float)
    grid_pts = grid_pts[rng.random(len(grid_pts)) < 0.4]
    shift = rng.integers(0, 30, len(grid_pts))
    right = grid_pts - np.column_stack([shift, np.zeros(len(grid_pts))])
    right = np.vstack([right, right[:7]])
    for pts in (grid_pts, right):
        tri = delaunay.triangulate(pts)
        area = _circumcircle_is_empty(pts, tri)
        assert area == pytest.approx(ConvexHull(np.unique(pts, axis=0)).volume)


def test_triangulate_degenerate_inputs_give_no_triangles():
    assert delaunay.triangulate(np.zeros((2, 2))).shape == (0, 3)
    assert delaunay.triangulate(np.array([[0, 0], [1, 1], [2, 2], [3, 3]])).shape == (0, 3)
    assert delaunay.triangulate(np.array([[0, 0], [0, 0], [5, 5], [5, 5]])).shape == (0, 3)


def test_rasterize_covers_the_hull_exactly():
    verts = np.array([[2.0, 2.0], [30.0, 2.0], [2.0, 20.0], [30.0, 20.0]])
    tri = delaunay.triangulate(verts)
    tmap = delaunay.rasterize_triangles(verts, tri, 25, 35)
    inside = np.zeros((25, 35), bool)
    inside[2:21, 2:31] = True
    assert np.array_equal(tmap >= 0, inside)
    # a pixel strictly inside one triangle gets that triangle
    from matplotlib.path import Path

    for t, (i, j, k) in enumerate(tri):
        path = Path(verts[[i, j, k]])
        vv, uu = np.nonzero(tmap == t)
        # Pick's theorem: a triangle's pixels are at least its interior lattice points and at
        # most its closed ones (area A, B lattice points on its edges)
        a, b, c = verts[[i, j, k]].astype(np.int64)
        area = abs((b - a)[0] * (c - a)[1] - (b - a)[1] * (c - a)[0]) / 2
        boundary = sum(np.gcd(*np.abs(q - p)) for p, q in ((a, b), (b, c), (c, a)))
        assert area - boundary / 2 + 1 <= len(vv) <= area + boundary / 2 + 1, (len(vv), area, boundary)
        assert path.contains_points(np.column_stack([uu, vv]), radius=1e-6).all() or \
            path.contains_points(np.column_stack([uu, vv]), radius=-1e-6).all()


# ----------------------------------------------------------------------- grid
def test_disparity_grid_spreads_to_the_3x3_neighbourhood():
    pts = np.array([[25, 25, 10], [85, 25, 30]], np.int32)  # cells (1, 1) and (1, 4)
    lists, counts = grid.disparity_grid(pts, (100, 60), 20, 0, 40)
    assert lists.shape == (3, 5, 41) and counts.shape == (3, 5)

    def cell(gy, gx):
        return list(lists[gy, gx, :counts[gy, gx]])

    for gy in range(3):
        assert cell(gy, 0) == [9, 10, 11]
        assert cell(gy, 2) == [9, 10, 11]
        assert cell(gy, 3) == [29, 30, 31]
        assert cell(gy, 4) == [29, 30, 31]
    assert cell(1, 1) == [9, 10, 11]
    # right image: the first point sits at u - d = 15 -> cell x 0
    lists_r, counts_r = grid.disparity_grid(pts, (100, 60), 20, 0, 40, right_image=True)
    assert list(lists_r[1, 2, :counts_r[1, 2]]) == [29, 30, 31]
    assert list(lists_r[1, 1, :counts_r[1, 1]]) == [9, 10, 11, 29, 30, 31]
    # clipped to the search range
    lists, counts = grid.disparity_grid(np.array([[5, 5, 0]]), (20, 20), 20, 0, 40)
    assert list(lists[0, 0, :counts[0, 0]]) == [0, 1]


# ------------------------------------------------------------------ matching
def test_prior_table_and_radius():
    p = matching.prior_table(0.02, 3.0, 1.0, 4)
    expect = [int((np.log(3) - np.log(3 + np.exp(-k * k / 2.0))) / 0.02) for k in range(4)]
    assert list(p) == expect == [-14, -9, -2, 0]
    assert matching.plane_radius(1.0, 2.0) == 2
    assert matching.plane_radius(1.0, 3.0) == 3
    assert matching.plane_radius(0.5, 1.0) == 2


# ----------------------------------------------------------- post-processing
def test_gap_interpolation():
    d = np.full((1, 12), -1.0, np.float32)
    d[0, [0, 3, 4, 7]] = [5.0, 6.0, 10.0, 30.0]
    out = postprocess.interpolate_gaps(d, 3)
    # gap 1..2 between 5 and 6 (differ < 3): mean; gap 5..6 between 10 and 30: the smaller
    np.testing.assert_allclose(out[0, :8], [5, 5.5, 5.5, 6, 10, 10, 10, 30])
    assert np.all(out[0, 8:] < 0)  # no right neighbour: untouched
    # too long a gap stays
    d = np.full((1, 10), -1.0, np.float32)
    d[0, [0, 9]] = 4.0
    assert (postprocess.interpolate_gaps(d, 3)[0, 1:9] < 0).all()
    assert np.allclose(postprocess.interpolate_gaps(d, 8)[0], 4.0)
    # extrapolation to the borders (rows, then columns)
    d = np.full((4, 6), -1.0, np.float32)
    d[1, 2] = 7.0
    out = postprocess.interpolate_gaps(d, 100, extrapolate=True)
    assert np.allclose(out, 7.0)
    # columns are filled after rows
    d = np.full((5, 1), -1.0, np.float32)
    d[0, 0], d[4, 0] = 2.0, 3.0
    np.testing.assert_allclose(postprocess.interpolate_gaps(d, 3)[:, 0], [2, 2.5, 2.5, 2.5, 3])


def test_small_segment_removal():
    d = np.full((30, 30), 10.0, np.float32)
    d[5:8, 5:8] = 50.0             # 9 px blob
    d[20:, 20:] = -1.0             # invalid block
    d[0, 0:4] = [12.0, 13.0, 14.0, 15.0]  # chained steps of 1 stay connected to ... row 1 (10)
    out = postprocess.remove_small_segments(d, 1.0, 10)
    assert (out[5:8, 5:8] < 0).all()
    assert (out[10:15, 10:15] == 10.0).all()
    # the steps 12..15 form one chain, connected to nothing at 10 (|12-10| = 2): 4 px < 10
    assert (out[0, 0:4] < 0).all()
    out = postprocess.remove_small_segments(d, 1.0, 9)   # size 9 is not < 9
    assert (out[5:8, 5:8] == 50.0).all()
    # diagonal neighbours are not connected (4-connectivity)
    e = np.full((4, 4), -1.0, np.float32)
    e[0, 0] = e[1, 1] = 3.0
    assert (postprocess.remove_small_segments(e, 1.0, 2) < 0).all()


def test_left_right_check():
    dl = np.full((1, 20), 4.0, np.float32)
    dr = np.full((1, 20), 4.0, np.float32)
    dr[0, 6] = 9.0     # left pixel 10 maps to right 6
    ol, orr = postprocess.left_right_check(dl, dr, 2)
    assert ol[0, 10] < 0 and ol[0, 11] == 4.0
    assert (ol[0, :4] < 0).all()       # u - d < 0: no partner
    assert orr[0, 6] < 0               # right pixel 6 with d 9 -> left 15 has 4
    assert (orr[0, 16:] < 0).all()     # u + d >= 20
    # subsampled maps: columns are u // 2
    ol, _ = postprocess.left_right_check(np.full((1, 10), 4.0, np.float32),
                                         np.full((1, 10), 4.0, np.float32), 2, step=2)
    assert (ol[0, 2:] == 4.0).all() and (ol[0, :2] < 0).all()


def test_adaptive_mean_weights():
    d = np.full((1, 9), 10.0, np.float32)
    d[0, 4] = 11.0
    out = postprocess.adaptive_mean(d)
    # centre: taps 0..7 (offsets -4..+3) all |dd| < 2 -> weight 4: mean of 7 tens and one 11
    assert out[0, 4] == pytest.approx((7 * 10 + 11) / 8)
    d = np.full((1, 9), 10.0, np.float32)
    d[0, 5] = 15.0                      # |dd| = 5 -> weight 2 (step) / 0 (linear)
    d[0, 6] = 30.0                      # |dd| = 20 -> 0
    d[0, 7] = -1.0                      # invalid -> ignored
    step = postprocess.adaptive_mean(d)
    # u = 3: taps 0..6 (-1 is outside): five 10s (w 4), one 15 (w 2), the 30 (w 0)
    assert step[0, 3] == pytest.approx((5 * 10 * 4 + 2 * 15) / (5 * 4 + 2))
    assert step[0, 7] < 0
    linear = postprocess.adaptive_mean(d, linear=True)
    assert linear[0, 3] == pytest.approx(10.0)


def test_median_filter_ignores_invalid_taps():
    d = np.full((1, 9), 3.0, np.float32)
    d[0, 4] = 50.0
    d[0, 2] = -1.0
    out = postprocess.median_filter(d)
    assert out[0, 4] == 3.0 and out[0, 2] < 0
    d = np.full((7, 7), 1.0, np.float32)
    d[3, 3] = 9.0
    assert np.all(postprocess.median_filter(d) == 1.0)


def test_median_network_sorts_every_0_1_input():
    import itertools

    for bits in itertools.product([0, 1], repeat=7):
        a = list(bits)
        for i, j in postprocess.MEDIAN_NETWORK:
            a[i], a[j] = min(a[i], a[j]), max(a[i], a[j])
        assert a == sorted(bits)


def test_median_filter_equals_a_direct_implementation(rng):
    d = rng.uniform(0, 30, (23, 31)).astype(np.float32)
    d[rng.random(d.shape) < 0.3] = -1.0

    def pass_rows(x):
        out = x.copy()
        for v in range(x.shape[0]):
            for u in range(x.shape[1]):
                if x[v, u] < 0:
                    continue
                win = x[v, max(u - 3, 0):u + 4]
                win = np.sort(win[win >= 0])
                out[v, u] = win[len(win) // 2]
        return out

    expect = pass_rows(pass_rows(d).T).T
    assert np.array_equal(postprocess.median_filter(d), expect)


@pytest.mark.parametrize("linear", [False, True])
def test_adaptive_mean_equals_a_direct_implementation(rng, linear):
    d = rng.uniform(0, 12, (17, 23)).astype(np.float32)
    d[rng.random(d.shape) < 0.25] = -1.0

    def weight(x, c):
        delta = abs(x - c)
        if linear:
            return max(0.0, 4.0 - delta)
        return 4.0 if delta < 2 else (2.0 if delta < 8 else 0.0)

    def pass_rows(x):
        out = x.copy()
        for v in range(x.shape[0]):
            for u in range(x.shape[1]):
                c = x[v, u]
                if c < 0:
                    continue
                taps = [t for t in x[v, max(u - 4, 0):u + 4] if t >= 0]
                wts = [weight(t, c) for t in taps]
                out[v, u] = np.dot(wts, taps) / sum(wts)
        return out

    expect = pass_rows(pass_rows(d).T).T
    np.testing.assert_allclose(postprocess.adaptive_mean(d, linear=linear), expect, rtol=1e-5)


def test_row_bands_cover_every_row_once():
    from canopy_stereo.elas.parallel import row_bands

    for n_rows, n_bands in [(1, 4), (7, 3), (100, 8), (5, 5), (3, 10)]:
        bands = row_bands(n_rows, n_bands)
        assert len(bands) <= n_bands
        rows = [r for a, b in bands for r in range(a, b)]
        assert rows == list(range(n_rows))
