"""The optimised ELAS kernels give exactly (bit for bit) what straightforward
implementations of the same definitions give.

Each reference below is a plain transcription of the stage's definition (the
kernels as they were before they were tuned for speed), kept here on purpose: the
package's kernels are free to change their loops, memory layout and branches, never
their output. Inputs: random maps/images, and the real intermediate maps of an ELAS
run on the bundled Middlebury Plants pair (examples/plants).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from canopy_stereo.elas import delaunay, descriptor, grid, matching, postprocess, support
from canopy_stereo.elas.core import elas_run
from canopy_stereo.elas.params import make_params
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.images import read_image

REPO = Path(__file__).resolve().parents[2]
INVALID = np.float32(-1.0)


def same_bits(a, b) -> bool:
    """Equal shape, dtype and bytes (so -0.0 != 0.0 and NaN == NaN of the same payload)."""
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


# --------------------------------------------------------------------------- inputs
@pytest.fixture(scope="module")
def plants():
    """A 320x240 grey crop of the real Plants pair and its ELAS intermediates."""
    left = read_image(REPO / "examples" / "plants" / "left.png", color=False)
    right = read_image(REPO / "examples" / "plants" / "right.png", color=False)
    gl = np.ascontiguousarray(left[120:360, 240:560])
    gr = np.ascontiguousarray(right[120:360, 240:560])
    p = make_params("robotics", disp_min=0, disp_max=120)
    desc, tex, pts, maps = _intermediates(gl, gr, p)
    disp_l, _ = matching.dense_match(*_match_args(maps[False], p, 1, 1, False))
    disp_r, _ = matching.dense_match(*_match_args(maps[True], p, -1, 1, False))
    return dict(left=gl, right=gr, params=p, desc=desc, tex=tex, support=pts, maps=maps,
                disp=(disp_l, disp_r))


def _intermediates(gl, gr, p, row_step=1):
    """ELAS's maps of a grey pair before dense matching: ``(desc, tex, support, maps)``,
    ``maps[right_image]`` the arguments of matching.dense_match (triangle map rasterised on
    every ``row_step``-th row, as ELAS does with subsampling)."""
    desc_l, tex_l = descriptor.compute_descriptors(gl)
    desc_r, tex_r = descriptor.compute_descriptors(gr)
    pts = support.support_points(desc_l, desc_r, tex_l, tex_r, p)
    maps = {}
    for right_image in (False, True):
        own, other, tex = (desc_r, desc_l, tex_r) if right_image else (desc_l, desc_r, tex_l)
        vert, tri, planes, valid = delaunay.triangle_planes(pts, right_image=right_image)
        lists, counts = grid.disparity_grid(pts, (gl.shape[1], gl.shape[0]), p.grid_size,
                                            p.disp_min, p.disp_max, right_image=right_image)
        tri_map = np.full(gl.shape, -1, np.int32)
        delaunay.rasterize_triangles_into(vert, tri, tri_map, row_step=row_step)
        radius = matching.plane_radius(p.sigma, p.sradius)
        prior = matching.prior_table(p.beta, p.gamma, p.sigma, radius + 1)
        maps[right_image] = dict(desc_own=own, desc_other=other, tex_own=tex, tri_map=tri_map,
                                 planes=planes, valid=valid, lists=lists, counts=counts,
                                 prior=prior, radius=radius, vertices=vert, triangles=tri)
    return (desc_l, desc_r), (tex_l, tex_r), pts, maps


def _match_args(m, p, sign, step, subpixel):
    return (m["desc_own"], m["desc_other"], m["tex_own"], m["tri_map"], m["planes"], m["valid"],
            m["lists"], m["counts"], p.grid_size, m["prior"], m["radius"], sign, p.disp_min,
            p.disp_max, p.match_texture, step, subpixel)


def random_disparity(rng, shape, *, invalid=0.3, integer=True, lo=0, hi=40):
    """float32 map with smooth-ish patches, ``invalid`` share of -1 pixels."""
    d = rng.integers(lo, hi, shape).astype(np.float32)
    d = np.round(0.5 * d + 0.5 * np.roll(d, 1, axis=1)) if integer else \
        (0.5 * d + 0.5 * np.roll(d, 1, axis=1) + rng.uniform(-0.5, 0.5, shape)).astype(np.float32)
    d = d.astype(np.float32)
    d[rng.random(shape) < invalid] = INVALID
    return d


# ------------------------------------------------------------- left-right check
def reference_lr_check(d_left, d_right, threshold, step):
    h, w = d_left.shape
    out_l, out_r = d_left.copy(), d_right.copy()
    inv_step = 1.0 / step
    for v in range(h):
        for c in range(w):
            d = d_left[v, c]
            if d >= 0:
                x = (c * step - float(d)) * inv_step + 0.5
                c2 = int(x) if x >= 0 else -1
                if c2 >= w or c2 < 0 or d_right[v, c2] < 0 or \
                        abs(d - d_right[v, c2]) > threshold:
                    out_l[v, c] = INVALID
            d = d_right[v, c]
            if d >= 0:
                c1 = int(min((c * step + float(d)) * inv_step + 0.5, w))  # (inf: outside)
                if c1 >= w or d_left[v, c1] < 0 or abs(d - d_left[v, c1]) > threshold:
                    out_r[v, c] = INVALID
    return out_l, out_r


@pytest.mark.parametrize("step", [1, 2])
@pytest.mark.parametrize("integer", [True, False])
def test_left_right_check_is_exact_on_random_maps(rng, step, integer):
    shape = (37, 53)
    d_left = random_disparity(rng, shape, integer=integer, hi=30)
    d_right = random_disparity(rng, shape, integer=integer, hi=30)
    # make many pairs consistent so that both outcomes occur
    for v in range(shape[0]):
        for c in range(shape[1]):
            x = int((c * step - float(d_left[v, c])) / step + 0.5)
            if d_left[v, c] >= 0 and 0 <= x < shape[1] and rng.random() < 0.6:
                d_right[v, x] = d_left[v, c] + np.float32(rng.choice([0.0, 1.0, 2.5]))
    ref_l, ref_r = reference_lr_check(d_left, d_right, 2.0, step)
    got_l, got_r = postprocess.left_right_check(d_left, d_right, 2.0, step=step)
    assert same_bits(got_l, ref_l) and same_bits(got_r, ref_r)
    assert (ref_l < 0).sum() > (d_left < 0).sum()         # the check did something
    only_l, none_r = postprocess.left_right_check(d_left, d_right, 2.0, step=step,
                                                  want_right=False)
    assert none_r is None and same_bits(only_l, ref_l)


def test_left_right_check_is_exact_with_non_finite_values(rng):
    """NaN and infinities in either map (the vector check's partner columns are clipped
    before the conversion): the same maps as the scalar definition."""
    shape = (9, 45)                     # 40 columns in vectors of 8, then 5 one by one
    d_left = random_disparity(rng, shape, integer=False, hi=20)
    d_right = random_disparity(rng, shape, integer=False, hi=20)
    for d in (d_left, d_right):
        d[rng.random(shape) < 0.05] = np.nan
        d[rng.random(shape) < 0.05] = np.inf
        d[rng.random(shape) < 0.05] = -np.inf
        d[rng.random(shape) < 0.05] = 1e30
    for step in (1, 2):
        ref_l, ref_r = reference_lr_check(d_left, d_right, 2.0, step)
        got_l, got_r = postprocess.left_right_check(d_left, d_right, 2.0, step=step)
        assert same_bits(got_l, ref_l) and same_bits(got_r, ref_r)


def test_left_right_check_is_exact_on_real_maps(plants):
    disp_l, disp_r = plants["disp"]
    ref_l, ref_r = reference_lr_check(disp_l, disp_r, 2, 1)
    got_l, got_r = postprocess.left_right_check(disp_l, disp_r, 2, step=1)
    assert same_bits(got_l, ref_l) and same_bits(got_r, ref_r)


# ------------------------------------------------------- small-segment removal
def reference_remove_small_segments(disp, sim_threshold, min_size):
    h, w = disp.shape
    out = disp.copy()
    label = np.zeros((h, w), np.int64)
    current = 0
    for v0 in range(h):
        for u0 in range(w):
            if disp[v0, u0] < 0 or label[v0, u0]:
                continue
            current += 1
            label[v0, u0] = current
            stack, members = [(v0, u0)], []
            while stack:
                v, u = stack.pop()
                members.append((v, u))
                for vv, uu in ((v, u - 1), (v, u + 1), (v - 1, u), (v + 1, u)):
                    if 0 <= vv < h and 0 <= uu < w and not label[vv, uu] and \
                            disp[vv, uu] >= 0 and abs(disp[vv, uu] - disp[v, u]) <= sim_threshold:
                        label[vv, uu] = current
                        stack.append((vv, uu))
            if len(members) < min_size:
                for v, u in members:
                    out[v, u] = INVALID
    return out


@pytest.mark.parametrize("integer", [True, False])
def test_small_segment_removal_is_exact_on_random_maps(rng, integer):
    disp = random_disparity(rng, (41, 57), integer=integer, hi=6, invalid=0.25)
    disp[0, :] = 3.0                   # segments touching every border
    disp[:, -1] = 5.0
    disp[5, 5] = np.nan                # a NaN pixel is a segment of its own
    for min_size in (1, 4, 30):
        ref = reference_remove_small_segments(disp, 1.0, min_size)
        assert same_bits(postprocess.remove_small_segments(disp, 1.0, min_size), ref)


def test_small_segment_removal_is_exact_on_real_maps(plants):
    for disp in plants["disp"]:
        ref = reference_remove_small_segments(disp, 1.0, 200)
        got = postprocess.remove_small_segments(disp, 1.0, 200)
        assert same_bits(got, ref)
        assert (got < 0).sum() > (disp < 0).sum()


@pytest.mark.parametrize("bands_per_thread", [1, 3, 30])
def test_segments_and_gaps_do_not_depend_on_the_row_bands(rng, plants, monkeypatch, bands_per_thread):
    """Small-segment removal and gap interpolation in row bands (and column bands), down to
    one-row bands: segments spanning many bands, runs joined across band edges, the same
    maps as the references."""
    import numba

    from canopy_stereo.elas import parallel

    monkeypatch.setattr(parallel, "BANDS_PER_THREAD", bands_per_thread)
    before = numba.get_num_threads()
    maps = [random_disparity(rng, (41, 57), integer=True, hi=4, invalid=0.1), plants["disp"][0]]
    try:
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            for disp in maps:
                for min_size in (4, 200):
                    assert same_bits(postprocess.remove_small_segments(disp, 1.0, min_size),
                                     reference_remove_small_segments(disp, 1.0, min_size))
                assert same_bits(postprocess.interpolate_gaps(disp, 5, extrapolate=True),
                                 reference_interpolate_gaps(disp, 5, True))
    finally:
        numba.set_num_threads(before)


# -------------------------------------------------------------- support points
def reference_candidate_grid(desc_l, desc_r, tex_l, tex_r, step, disp_min, disp_max,
                             support_texture, support_threshold, lr_threshold):
    """Candidate cells by the definition in canopy_stereo.elas.support (numpy per candidate)."""
    h, w = desc_l.shape[:2]
    off, border, margin = support.SUPPORT_SAMPLE_OFFSET, descriptor.BORDER, support.SUPPORT_MARGIN
    thr = np.float32(support_threshold)

    def cost_vector(desc, u, v):
        return np.concatenate([desc[v - off, u - off], desc[v - off, u + off],
                               desc[v + off, u - off], desc[v + off, u + off]]).astype(np.int32)

    def best(desc_own, desc_other, tex_own, u, v, sign):
        if tex_own[v, u] < support_texture:
            return -1
        dmax = min(disp_max, u - off - border) if sign > 0 else \
            min(disp_max, w - 1 - border - off - u)
        dmin = max(disp_min, 0)
        if dmax - dmin + 1 < 11:
            return -1
        own = cost_vector(desc_own, u, v)
        costs = np.array([np.abs(own - cost_vector(desc_other, u - sign * d, v)).sum()
                          for d in range(dmin, dmax + 1)], np.int64)
        k = int(np.argmin(costs))
        second = np.min(np.delete(costs, k))
        ok = np.float32(costs[k]) < thr * np.float32(second)
        return dmin + k if ok else -1

    rows, cols = (h - 1) // step + 1, (w - 1) // step + 1
    out = np.full((rows, cols), -1, np.int32)
    for i in range(rows):
        v = i * step
        if v < margin or v > h - 1 - margin:
            continue
        for j in range(cols):
            u = j * step
            if u < margin or u > w - 1 - margin:
                continue
            d = best(desc_l, desc_r, tex_l, u, v, 1)
            if d < 0:
                continue
            d_back = best(desc_r, desc_l, tex_r, u - d, v, -1)
            if d_back >= 0 and abs(d - d_back) <= lr_threshold:
                out[i, j] = d
    return out


def test_support_candidates_are_exact_on_real_images(plants):
    (dl, dr), (tl, tr) = plants["desc"], plants["tex"]
    for step, dmin, dmax, thr in ((5, 0, 120, 0.85), (4, 20, 60, 0.95)):
        ref = reference_candidate_grid(dl, dr, tl, tr, step, dmin, dmax, 10, thr, 2)
        got = support.candidate_grid(dl, dr, tl, tr, step, dmin, dmax, 10, thr, 2)
        assert same_bits(got, ref)
        assert (ref >= 0).sum() > 100


def test_support_candidates_are_exact_on_random_images(rng):
    img = rng.integers(0, 256, (45, 70), dtype=np.uint8)
    shifted = np.roll(img, -7, axis=1)
    dl, tl = descriptor.compute_descriptors(img)
    dr, tr = descriptor.compute_descriptors(shifted)
    ref = reference_candidate_grid(dl, dr, tl, tr, 3, 0, 30, 10, 0.9, 2)
    assert same_bits(support.candidate_grid(dl, dr, tl, tr, 3, 0, 30, 10, 0.9, 2), ref)
    assert (ref == 7).sum() > 10


def reference_remove_inconsistent(grid, window, threshold, min_support):
    grid = grid.copy()
    rows, cols = grid.shape
    for j in range(cols):
        for i in range(rows):
            d = grid[i, j]
            if d < 0:
                continue
            near = grid[max(i - window, 0):i + window + 1, max(j - window, 0):j + window + 1]
            if ((near >= 0) & (np.abs(near - d) <= threshold)).sum() < min_support:
                grid[i, j] = -1
    return grid


def test_inconsistent_support_removal_is_exact(rng, plants):
    """The filter updates in place (columns outer, rows inner): later points see the
    earlier removals; the count may stop early, the result may not change."""
    p = plants["params"]
    real = support.candidate_grid(*plants["desc"], *plants["tex"], p.candidate_stepsize,
                                  p.disp_min, p.disp_max, p.support_texture,
                                  p.support_threshold, p.lr_threshold)
    noisy = rng.integers(0, 30, (40, 50)).astype(np.int32)
    noisy[rng.random(noisy.shape) < 0.4] = -1
    for cells, args in ((real, (5, 5, 5)), (noisy, (5, 5, 5)), (noisy, (2, 3, 4))):
        ref = reference_remove_inconsistent(cells, *args)
        got = support.remove_inconsistent(cells.copy(), *args)
        assert same_bits(got, ref)
        assert (ref < 0).sum() > (cells < 0).sum() and (ref >= 0).any()


# ------------------------------------------------------------------- the whole run
def _runs_with_one_and_two_threads(left, right, p):
    import numba

    before = numba.get_num_threads()
    try:
        runs = []
        for threads in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(threads)
            runs.append(elas_run(left, right, p, want_right=True))
    finally:
        numba.set_num_threads(before)
    return runs


def _assert_same_runs(runs):
    for other in runs[1:]:
        for name in ("disp_left", "disp_right", "support", "triangles_left", "triangles_right"):
            assert same_bits(getattr(other, name), getattr(runs[0], name)), name


@pytest.mark.parametrize("preset,extra", [
    ("middlebury", {"subpixel": True}),
    # every filter of both maps, each map's post-processing a pool task (its row bands
    # then run inside the task)
    ("robotics", {"postprocess_only_left": False, "filter_median": True}),
    # subsampling: the row bands split some pairs of matched rows differently
    ("robotics", {"subsampling": True, "postprocess_only_left": False}),
])
def test_elas_run_is_deterministic_across_thread_counts(plants, preset, extra):
    p = make_params(preset, disp_min=0, disp_max=120, **extra)
    _assert_same_runs(_runs_with_one_and_two_threads(plants["left"], plants["right"], p))


@pytest.mark.slow
def test_elas_run_at_1280x720_is_the_same_with_two_threads():
    """HD (the bundled Plants pair resized to 1280x720, disparities to about 140 px): the
    two-thread run (row bands, left/right tasks) gives the one-thread maps bit for bit."""
    left, right = _hd_plants()
    runs = _runs_with_one_and_two_threads(left, right, make_params("robotics", disp_max=255))
    _assert_same_runs(runs)
    assert (runs[0].disp_left >= 0).mean() > 0.5


# --------------------------------------------------------------- SIMD intrinsics
def _reference_first_min():
    """One pixel's first minimum by the definition (simd.quad_first_min's docstring)."""
    from numba import njit

    from canopy_stereo.elas.simd import sad_reference

    @njit
    def first_min(own, a, other, b, stride, cell, runs, w_lo, w_hi, radius, window_prior, mu,
                  hi, flag):
        best_e, best_d = 2147483647, -1
        for run in (0, 2):
            for j in range(runs[run], runs[run + 1]):
                d = cell[j]
                if abs(d - mu) <= radius or d > hi:
                    continue
                e = sad_reference(own, a, other, b + d * stride, 16)
                if e < best_e:
                    best_e, best_d = e, d
        for d in range(w_lo, w_hi + 1):
            if abs(d - mu) > radius or d > hi:
                continue
            e = sad_reference(own, a, other, b + d * stride, 16)
            if flag:
                e += window_prior[d - mu + radius]
            if e < best_e:
                best_e, best_d = e, d
        return best_d

    return first_min


def _first_min_both(pixels, spread, row_bytes=0):
    """A fresh (uncached) kernel: quad_first_min (``pixels`` 4), octo_first_min (8),
    hexa_first_min (16) or penta_first_min (20), or (``spread`` 2: pixels every second
    column, the second ten ``row_bytes`` further) penta_first_min_spread2_two_rows, next to
    the one-pixel-at-a-time definition, so that it is compiled with the current
    simd.PSADBW_WIDTH. Row ``i`` of ``groups``: own offset, other offset, stride, -, mu (20),
    largest d (20), prior flag (20), runs (4), window (2)."""
    from numba import njit

    from canopy_stereo.elas import simd
    from canopy_stereo.elas.simd import GROUP_LANES, quad_first_min

    names = {4: "octo", 8: "octo", 16: "hexa", 20: "penta"}   # (4: not called)
    group = getattr(simd, names[pixels] + ("_first_min" if spread == 1
                                           else "_first_min_spread2_two_rows"))
    lane_bytes = 16 * spread
    per_row = pixels // 2 if spread == 2 else pixels
    reference = _reference_first_min()

    if spread == 2:
        @njit
        def call(own, a, other, b, stride, cell, runs, w_lo, w_hi, radius, window_prior, lanes,
                 best):
            group(own, a, other, b, stride, cell, runs[0], runs[1], runs[2], runs[3], w_lo, w_hi,
                  radius, window_prior, lanes, best, row_bytes)
    else:
        @njit
        def call(own, a, other, b, stride, cell, runs, w_lo, w_hi, radius, window_prior, lanes,
                 best):
            group(own, a, other, b, stride, cell, runs[0], runs[1], runs[2], runs[3], w_lo, w_hi,
                  radius, window_prior, lanes, best)

    @njit
    def both(own, other, groups, cell, radius, window_prior):
        n = groups.shape[0]
        got = np.empty((n, pixels), np.int64)
        ref = np.empty((n, pixels), np.int64)
        lanes = np.zeros(3 * GROUP_LANES, np.int32)
        best = np.empty(GROUP_LANES, np.int32)
        for i in range(n):
            a, b, stride = groups[i, 0], groups[i, 1], groups[i, 2]
            mu, hi, flag = groups[i, 4:24], groups[i, 24:44], groups[i, 44:64]
            runs = groups[i, 64:68]
            w_lo, w_hi = groups[i, 68], groups[i, 69]
            if pixels == 4:
                got[i] = quad_first_min(own, a, other, b, stride, cell, runs[0], runs[1],
                                        runs[2], runs[3], w_lo, w_hi, radius, window_prior,
                                        mu[0], mu[1], mu[2], mu[3], hi[0], hi[1], hi[2], hi[3],
                                        flag[0] != 0, flag[1] != 0, flag[2] != 0, flag[3] != 0)
                continue
            for k in range(pixels):
                lanes[k] = mu[k]
                lanes[GROUP_LANES + k] = hi[k]
                lanes[2 * GROUP_LANES + k] = flag[k]
            call(own, a, other, b, stride, cell, runs, w_lo, w_hi, radius, window_prior, lanes,
                 best)
            got[i] = best[:pixels]
        for i in range(n):
            a, b, stride = groups[i, 0], groups[i, 1], groups[i, 2]
            runs = groups[i, 64:68]
            for k in range(pixels):
                at = lane_bytes * (k % per_row) + row_bytes * (k // per_row)
                ref[i, k] = reference(own, a + at, other, b + at, stride, cell, runs,
                                      groups[i, 68], groups[i, 69], radius, window_prior,
                                      groups[i, 4 + k], groups[i, 24 + k], groups[i, 44 + k] != 0)
        return got, ref

    return both


@pytest.mark.parametrize("pixels,spread,row_bytes", [(4, 1, 0), (8, 1, 0), (16, 1, 0), (20, 1, 0),
                                                     (20, 2, 0), (20, 2, 352)])
@pytest.mark.parametrize("width", [64, 32, 16, 0])
def test_first_min_of_four_to_twenty_pixels_equals_one_pixel_at_a_time(rng, monkeypatch, width,
                                                                       pixels, spread, row_bytes):
    """Four (eight, sixteen, twenty) pixels' first minima over two runs of grid candidates
    and a window (own prior, window and largest disparity per pixel, unmatched pixels),
    ties included, at every psadbw width (0: portable IR), with the prior in a register
    (small radius, AVX2 / AVX-512) and in memory; neighbouring pixels and (subsampling)
    pixels every second column, also on two rows ``row_bytes`` apart."""
    from canopy_stereo.elas import simd

    if width > simd.PSADBW_WIDTH:
        pytest.skip(f"this CPU has no {width}-byte psadbw")
    n, span = 300, 40
    levels = 3                                         # few byte values: many equal costs
    own = rng.integers(0, levels, 16 * spread * pixels * n + 64 + row_bytes, dtype=np.uint8)
    other = rng.integers(0, levels, 16 * (4 * span + 24 + 24 * spread) + row_bytes, dtype=np.uint8)
    cell = np.sort(rng.choice(span, 12, replace=False)).astype(np.int32)
    groups = np.zeros((n, 70), np.int64)
    groups[:, 0] = 16 * spread * pixels * np.arange(n)
    groups[:, 2] = rng.choice([-16, 16], n)
    groups[:, 1] = np.where(groups[:, 2] < 0, 16 * (span + 2), 16 * (2 * span + 2))
    groups[:, 4:24] = rng.integers(-5, span + 5, (n, 1)) + rng.integers(-3, 4, (n, 20))
    groups[:, 24:44] = rng.integers(span // 2, span, (n, 1)) + \
        np.arange(20) * rng.choice([-1, 1, 0], (n, 1)) // 3
    groups[:, 24:44][rng.random((n, 20)) < 0.1] = -1    # pixels that are not matched
    groups[:, 44:64] = rng.random((n, 20)) < 0.6
    groups[:, 64:68] = np.sort(rng.integers(0, len(cell) + 1, (n, 4)), axis=1)   # two runs
    groups[:, 68] = rng.integers(0, span // 2, n)
    groups[:, 69] = groups[:, 68] + rng.integers(-1, 12, n)
    monkeypatch.setattr(simd, "PSADBW_WIDTH", width)
    kernel = _first_min_both(pixels, spread, row_bytes)
    for radius in (2, 3, 5, 7, 9):
        table = matching.prior_table(0.02, 3.0, radius / 2.0, radius + 1)
        got, ref = kernel(own, other, groups, cell, radius, matching.window_prior(table, radius))
        assert np.array_equal(got, ref), f"radius {radius}"
        assert (ref >= 0).mean() > 0.5 and (ref < 0).any()


def test_candidate_ranks_count_the_candidates_below_each_disparity(plants):
    lists, counts = plants["maps"][False]["lists"], plants["maps"][False]["counts"]
    ranks = grid.candidate_ranks(lists, counts)
    for gy, gx in ((0, 0), (3, 5), (lists.shape[0] - 1, lists.shape[1] - 1)):
        cell = lists[gy, gx, :counts[gy, gx]]
        expect = [(cell < d).sum() for d in range(lists.shape[2] + 1)]
        assert np.array_equal(ranks[gy, gx], expect)


# ------------------------------------------------------------------ dense matching
def _reference_match_kernel():
    """The dense matching definition, one pixel at a time (matching.py's module
    docstring), compiled fresh for the test."""
    from numba import njit

    from canopy_stereo.elas.simd import sad_reference

    @njit
    def match(desc_own, desc_other, tex_own, tri_map, planes, plane_valid, grid_lists,
              grid_counts, grid_size, prior, radius, sign, disp_min, disp_max, match_texture,
              step, subpixel):
        h, w, _ = desc_own.shape
        fo = desc_own.reshape(-1)
        ft = desc_other.reshape(-1)
        oh, ow = (h + step - 1) // step, (w + step - 1) // step
        disp = np.full((oh, ow), -1.0, np.float32)
        offs = np.zeros((oh, ow), np.float32)
        for r in range(oh):
            v = r * step
            for c in range(ow):
                u = c * step
                if u < 2 or u >= w - 2:
                    continue
                t = tri_map[v, u]
                if t < 0 or tex_own[v, u] < match_texture:
                    continue
                if sign > 0:
                    d_lo, d_hi = max(disp_min, u - (w - 3)), min(disp_max, u - 2)
                else:
                    d_lo, d_hi = max(disp_min, 2 - u), min(disp_max, w - 3 - u)
                mu = int(planes[t, 0] * u + planes[t, 1] * v + planes[t, 2])
                a = (v * w + u) * 16
                best_e, best_d = 2147483647, -1
                gy, gx = v // grid_size, u // grid_size
                for j in range(grid_counts[gy, gx]):
                    d = grid_lists[gy, gx, j]
                    if abs(d - mu) <= radius or d < d_lo or d > d_hi:
                        continue
                    e = sad_reference(fo, a, ft, a - sign * d * 16, 16)
                    if e < best_e:
                        best_e, best_d = e, d
                for d in range(max(mu - radius, d_lo), min(mu + radius, d_hi) + 1):
                    e = sad_reference(fo, a, ft, a - sign * d * 16, 16)
                    if plane_valid[t]:
                        e += prior[abs(d - mu)]
                    if e < best_e:
                        best_e, best_d = e, d
                if best_d < 0:
                    continue
                disp[r, c] = best_d
                if subpixel and best_d - 1 >= d_lo and best_d + 1 <= d_hi:
                    b = a - sign * best_d * 16
                    c0 = sad_reference(fo, a, ft, b, 16)
                    cm = sad_reference(fo, a, ft, b + sign * 16, 16)
                    cp = sad_reference(fo, a, ft, b - sign * 16, 16)
                    if c0 <= cm and c0 <= cp and cm + cp > 2 * c0:
                        offs[r, c] = np.float32(0.5 * (cm - cp) / (cm + cp - 2 * c0))
        return disp, offs

    return match


@pytest.mark.parametrize("subpixel", [False, True])
@pytest.mark.parametrize("step", [1, 2])
def test_dense_matching_is_exact_on_real_images(plants, subpixel, step):
    reference = _reference_match_kernel()
    p = plants["params"]
    for right_image, sign in ((False, 1), (True, -1)):
        args = _match_args(plants["maps"][right_image], p, sign, step, subpixel)
        ref = reference(*args)
        got = matching.dense_match(*args)
        assert same_bits(got[0], ref[0]) and same_bits(got[1], ref[1])
        assert (ref[0] >= 0).mean() > 0.3


def _hd_plants():
    """The bundled Plants pair resized to 1280x720 (disparities to about 140 px), grey."""
    import cv2

    size = (1280, 720)
    return tuple(cv2.resize(read_image(REPO / "examples" / "plants" / f"{side}.png", color=False),
                            size) for side in ("left", "right"))


def _assert_subsampled_matching_is_exact(gl, gr, preset, **params):
    """Subsampled dense matching of both images (triangle map on the matched rows only) equals
    the one-pixel-at-a-time definition, refinement included."""
    reference = _reference_match_kernel()
    p = make_params(preset, **{"disp_min": 0, "disp_max": 255, "subsampling": True, **params})
    _, _, _, maps = _intermediates(gl, gr, p, row_step=2)
    for right_image, sign in ((False, 1), (True, -1)):
        args = _match_args(maps[right_image], p, sign, 2, True)
        ref = reference(*args)
        got = matching.dense_match(*args)
        assert same_bits(got[0], ref[0]) and same_bits(got[1], ref[1])
        assert (ref[0] >= 0).mean() > 0.3


def test_subsampled_matching_with_wide_grid_cells_is_exact(plants):
    """Grid cells of 36 pixels (eighteen matched pixels per cell row: ten, then eight)."""
    _assert_subsampled_matching_is_exact(plants["left"], plants["right"], "robotics",
                                         grid_size=36, disp_max=120)


@pytest.mark.slow
def test_subsampled_matching_at_1280x720_is_exact():
    _assert_subsampled_matching_is_exact(*_hd_plants(), "robotics")


@pytest.mark.slow
@pytest.mark.shared
def test_subsampled_matching_on_middlebury_is_exact(shared_data):
    base = shared_data / "middlebury_MiddEval3_trainingQ" / "Adirondack"
    gl, gr = (read_image(base / name, color=False) for name in ("im0.png", "im1.png"))
    _assert_subsampled_matching_is_exact(gl, gr, "middlebury")


def test_dense_matching_is_exact_with_steep_random_planes(plants, rng):
    """Random planes: neighbouring pixels get different predictions and prior flags
    (the four-pixel path masks each pixel's own window), also near the borders."""
    reference = _reference_match_kernel()
    p = plants["params"]
    m = dict(plants["maps"][False])
    n_tri = len(m["planes"])
    planes = np.zeros((n_tri, 3), np.float32)
    planes[:, 0] = rng.uniform(-0.9, 0.9, n_tri)
    planes[:, 1] = rng.uniform(-0.3, 0.3, n_tri)
    planes[:, 2] = rng.uniform(0, 120, n_tri)
    m["planes"] = planes
    m["valid"] = rng.random(n_tri) < 0.5
    for sign, own in ((1, False), (-1, True)):
        mm = dict(m, desc_own=plants["maps"][own]["desc_own"],
                  desc_other=plants["maps"][own]["desc_other"])
        for step in (1, 2):
            args = _match_args(mm, p, sign, step, True)
            ref = reference(*args)
            got = matching.dense_match(*args)
            assert same_bits(got[0], ref[0]) and same_bits(got[1], ref[1])


# ---------------------------------------------------------- gap interpolation
def reference_fill_line(line, max_gap, discon, extrapolate):
    n, count = len(line), 0
    for i in range(n):
        if line[i] >= 0:
            if 1 <= count <= max_gap and i - count > 0:
                d1, d2 = line[i - count - 1], line[i]
                fill = np.float32(0.5 * (float(d1) + float(d2))) if abs(d1 - d2) < discon \
                    else min(d1, d2)
                line[i - count:i] = fill
            count = 0
        else:
            count += 1
    if extrapolate:
        valid = np.flatnonzero(line >= 0)
        if len(valid):
            first, last = valid[0], valid[-1]
            line[max(first - max_gap, 0):first] = line[first]
            line[last + 1:min(last + 1 + max_gap, n)] = line[last]


def reference_interpolate_gaps(disp, max_gap, extrapolate):
    out = disp.copy()
    for v in range(out.shape[0]):
        reference_fill_line(out[v], max_gap, 3.0, extrapolate)
    for u in range(out.shape[1]):
        column = out[:, u].copy()
        reference_fill_line(column, max_gap, 3.0, extrapolate)
        out[:, u] = column
    return out


@pytest.mark.parametrize("max_gap,extrapolate", [(3, False), (5, True), (5000, True)])
def test_gap_interpolation_is_exact(rng, plants, max_gap, extrapolate):
    maps = [random_disparity(rng, (45, 61), integer=False, hi=30, invalid=0.4),
            postprocess.remove_small_segments(plants["disp"][0], 1.0, 200)]
    for disp in maps:
        ref = reference_interpolate_gaps(disp, max_gap, extrapolate)
        assert same_bits(postprocess.interpolate_gaps(disp, max_gap, extrapolate=extrapolate),
                         ref)


# ------------------------------------------------------------------- adaptive mean
def reference_adaptive_mean(disp, linear):
    """The former single weight formula ``(l * ramp + (1 - l) * step) * valid`` in float32,
    taps -4..+3 in order, rows then columns."""
    f32 = np.float32
    lin = f32(1.0 if linear else 0.0)

    def weight(d, c):
        delta = abs(d - c)
        step = f32(2.0) * f32(delta < 8.0) + f32(2.0) * f32(delta < 2.0)
        ramp = max(f32(0.0), f32(4.0) - delta)
        return (lin * ramp + (f32(1.0) - lin) * step) * f32(d >= 0)

    def one_pass(x):
        h, w = x.shape
        out = x.copy()
        for v in range(h):
            for u in range(w):
                c = x[v, u]
                if not c >= 0:
                    continue
                s, sw = f32(0.0), f32(0.0)
                for k in range(-4, 4):
                    d = x[v, u + k] if 0 <= u + k < w else f32(-1.0)
                    wt = weight(d, c)
                    s = f32(s + f32(wt * d))
                    sw = f32(sw + wt)
                out[v, u] = f32(s / sw)
        return out

    return np.ascontiguousarray(one_pass(np.ascontiguousarray(one_pass(disp).T)).T)


@pytest.mark.parametrize("linear", [False, True])
def test_adaptive_mean_is_exact(rng, plants, linear):
    crop = postprocess.interpolate_gaps(plants["disp"][0], 3)[100:140, 150:210]
    for disp in (random_disparity(rng, (23, 31), integer=False, hi=12, invalid=0.25), crop):
        ref = reference_adaptive_mean(np.ascontiguousarray(disp), linear)
        assert same_bits(postprocess.adaptive_mean(disp, linear=linear), ref)


# ----------------------------------------------------------- Delaunay and planes
def reference_delaunay(points):
    """The former numpy glue around the sweep: np.unique for first occurrences, a
    stable numpy argsort for the insertion order."""
    from canopy_stereo.elas import sweephull

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) < 3:
        return np.zeros((0, 3), np.int32)
    _, first = np.unique(pts, axis=0, return_index=True)
    first = np.sort(first)
    xs, ys = np.ascontiguousarray(pts[first, 0]), np.ascontiguousarray(pts[first, 1])
    if len(xs) < 3:
        return np.zeros((0, 3), np.int32)
    i0, i1, i2, ccx, ccy = sweephull._seed(xs, ys)
    if i0 < 0:
        return np.zeros((0, 3), np.int32)
    order = np.argsort((xs - ccx) ** 2 + (ys - ccy) ** 2, kind="stable")
    tri = sweephull._sweep(xs, ys, order, int(i0), int(i1), int(i2), float(ccx), float(ccy))
    return first[tri].astype(np.int32)


def reference_triangle_planes(points, right_image):
    points = np.asarray(points, dtype=np.int64).reshape(-1, 3)
    u_left, v, d = points[:, 0], points[:, 1], points[:, 2]
    u_own, u_other = (u_left - d, u_left) if right_image else (u_left, u_left - d)
    vertices = np.column_stack([u_own, v]).astype(np.float64)
    triangles = reference_delaunay(vertices)
    planes = delaunay.fit_planes(u_own, v, d, triangles)
    other = delaunay.fit_planes(u_other, v, d, triangles)
    valid = (np.abs(planes[:, 0]) < delaunay.MAX_PLANE_SLOPE) & \
        (np.abs(other[:, 0]) < delaunay.MAX_PLANE_SLOPE)
    return vertices, triangles, planes, valid


def test_delaunay_and_planes_are_exact(rng, plants):
    grid_pts = np.stack(np.meshgrid(np.arange(0, 60, 5), np.arange(0, 40, 5)), -1).reshape(-1, 2)
    cases = [plants["support"][:, :2],                  # real support points
             grid_pts,                                   # co-circular quadruples
             np.vstack([grid_pts, grid_pts[::3]]),       # repeated points
             np.vstack([grid_pts * -1.0, [[0.0, -0.0]]]),  # -0.0 equals 0.0
             rng.integers(0, 50, (200, 2)),              # many duplicates
             np.array([[0, 0], [1, 1], [2, 2], [3, 3]]),  # collinear
             np.zeros((2, 2))]
    for pts in cases:
        assert same_bits(delaunay.triangulate(pts), reference_delaunay(pts))
    for right_image in (False, True):
        got = delaunay.triangle_planes(plants["support"], right_image=right_image)
        ref = reference_triangle_planes(plants["support"], right_image)
        assert all(same_bits(a, b) for a, b in zip(got, ref))
        assert 0 < got[3].sum() < len(got[3]) or got[3].all()


# ------------------------------------------------------------------- rasterisation
def reference_rasterize(vertices, triangles, height, width):
    tri_map = np.full((height, width), -1, np.int32)
    eps = 1e-9
    for t, (i, j, k) in enumerate(triangles):
        (ax, ay), (bx, by), (cx, cy) = vertices[i], vertices[j], vertices[k]
        vmin = max(int(np.ceil(min(ay, by, cy) - eps)), 0)
        vmax = min(int(np.floor(max(ay, by, cy) + eps)), height - 1)
        for v in range(vmin, vmax + 1):
            y, lo, hi = float(v), np.inf, -np.inf
            for x0, y0, x1, y1 in ((ax, ay, bx, by), (bx, by, cx, cy), (cx, cy, ax, ay)):
                if y0 == y1:
                    if abs(y - y0) <= eps:
                        lo, hi = min(lo, x0, x1), max(hi, x0, x1)
                    continue
                if y < min(y0, y1) - eps or y > max(y0, y1) + eps:
                    continue
                x = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
                lo, hi = min(lo, x), max(hi, x)
            if lo > hi:
                continue
            u0, u1 = max(int(np.ceil(lo - eps)), 0), min(int(np.floor(hi + eps)), width - 1)
            if u1 >= u0:
                tri_map[v, u0:u1 + 1] = t
    return tri_map


def _assert_rasterised_rows(vertices, triangles, h, w, ref):
    """Every row, and (subsampled matching) every second row with the others untouched."""
    assert same_bits(delaunay.rasterize_triangles(vertices, triangles, h, w), ref)
    some = np.full((h, w), 12345, np.int32)
    delaunay.rasterize_triangles_into(vertices, triangles, some, row_step=2)
    assert same_bits(some[::2], ref[::2]) and (some[1::2] == 12345).all()
    for bad in (0, -2):     # no row at all: an error, not an untouched map
        with pytest.raises(CanopyStereoError, match="row_step must be 1 or more"):
            delaunay.rasterize_triangles_into(vertices, triangles, some, row_step=bad)


def test_rasterisation_is_exact(rng, plants):
    for right_image in (False, True):
        m = plants["maps"][right_image]
        h, w = plants["left"].shape
        ref = reference_rasterize(m["vertices"], m["triangles"], h, w)
        _assert_rasterised_rows(m["vertices"], m["triangles"], h, w, ref)
    # non-integer vertices, horizontal edges (on even and odd rows), triangles leaving the image
    vertices = np.vstack([rng.uniform(-10, 70, (30, 2)), [[5.0, 7.0], [25.0, 7.0], [15.0, 20.5],
                                                         [8.0, 12.0], [30.0, 12.0]]])
    triangles = np.vstack([rng.integers(0, 30, (40, 3)),
                           [[30, 31, 32], [33, 34, 32]]]).astype(np.int32)
    ref = reference_rasterize(vertices, triangles, 50, 60)
    _assert_rasterised_rows(vertices, triangles, 50, 60, ref)


def test_stable_argsort_equals_numpys_stable_sort(rng):
    from canopy_stereo.elas.sweephull import stable_argsort

    for n in (0, 1, 2, 3, 7, 64, 1000):
        keys = rng.integers(0, max(n // 3, 1), n).astype(np.float64)   # many ties
        keys[rng.random(n) < 0.1] = -0.0
        keys[rng.random(n) < 0.1] = 0.0
        assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))
    keys = rng.normal(size=777)
    assert np.array_equal(stable_argsort(keys), np.argsort(keys, kind="stable"))


def test_first_occurrences_equal_a_plain_dictionary(rng):
    """The hash set's first occurrences: a point's first index, found by a Python dict
    (-0.0 is 0.0; NaN equals nothing), for grids with many duplicates, support-like
    integer points (negative right-image columns), wide and random coordinates."""
    from canopy_stereo.elas.sweephull import _first_occurrences

    def reference(xs, ys):
        seen, first = set(), []
        for i, (x, y) in enumerate(zip(xs, ys)):
            if x != x or y != y:          # NaN: a point of its own
                first.append(i)
            elif (x + 0.0, y + 0.0) not in seen:
                seen.add((x + 0.0, y + 0.0))
                first.append(i)
        return np.array(first, np.int64)

    cases = [rng.integers(0, 6, (300, 2)), rng.integers(-255, 640, (1500, 2)) * [1, 0] +
             rng.integers(0, 480, (1500, 1)) // 5 * [0, 5], rng.normal(size=(400, 2)) * 1e6,
             np.array([[0.0, -0.0], [-0.0, 0.0], [np.nan, 1.0], [np.nan, 1.0], [1.0, 2.0]]),
             np.zeros((1, 2)), np.zeros((0, 2))]
    for pts in cases:
        pts = np.asarray(pts, np.float64)
        xs, ys = np.ascontiguousarray(pts[:, 0]), np.ascontiguousarray(pts[:, 1])
        assert np.array_equal(_first_occurrences(xs, ys), reference(xs, ys))


def test_support_row_buffers_hold_the_same_cost_vectors(plants):
    """The interleaved row buffer (CPUs without AVX-512BW) and the chunk-major one hold
    the same 64-byte cost vector of every column."""
    desc = plants["desc"][0]
    h, w = desc.shape[:2]
    words = desc.reshape(h, w * 16).view(np.uint64).reshape(h, w, 2)
    interleaved = support._row_buffer_interleaved(w)
    chunks = support._row_buffer_chunks(w)
    support._sample_into_interleaved(words, 40, interleaved)
    support._sample_into_chunks(words, 40, chunks)
    pad = support.CHUNK_PAD
    by_column = interleaved.view(np.uint64).reshape(w, support.SUPPORT_LANES)
    assert np.array_equal(chunks.reshape(support.SUPPORT_LANES, -1)[:, pad:pad + w], by_column.T)
    assert by_column[2:w - 2].any()


def test_support_search_by_eight_disparities_equals_one_at_a_time(rng):
    """The AVX-512 lowest-two search (chunk-major row buffers, 8 disparities per vector,
    lanes merged) gives the one-at-a-time search's lowest, second lowest and first best
    disparity, ties included, in both directions and with partial last groups."""
    from canopy_stereo.elas.simd import PSADBW_WIDTH

    if PSADBW_WIDTH != 64:
        pytest.skip("the eight-disparity search is compiled only with AVX-512BW")
    width, pad, lanes = 300, support.CHUNK_PAD, support.SUPPORT_LANES

    def chunk_major(flat):
        words = flat.view(np.uint64).reshape(width, lanes)
        out = np.zeros((lanes, width + 2 * pad), np.uint64)
        out[:, pad:pad + width] = words.T
        return out.reshape(-1)

    for levels in (2, 4, 256):       # few levels: many equal costs
        own = rng.integers(0, levels, width * support.SUPPORT_BYTES, dtype=np.uint8)
        other = rng.integers(0, levels, width * support.SUPPORT_BYTES, dtype=np.uint8)
        own_chunks, other_chunks = chunk_major(own), chunk_major(other)
        for _ in range(60):
            sign = int(rng.choice([-1, 1]))
            u = int(rng.integers(120, 180))
            dmin = int(rng.integers(0, 20))
            dmax = dmin + int(rng.integers(10, 100))
            ref = support._lowest_two_scalar(own, other, u * support.SUPPORT_BYTES, sign, dmin,
                                             dmax)
            got = support._lowest_two_chunks(own_chunks, other_chunks, u, sign, dmin, dmax)
            assert tuple(int(x) for x in got) == tuple(int(x) for x in ref)


# ------------------------------------------------------------ cells to match
def _cell_pixels(cells, grid_size, shape, step):
    """Per output pixel (rows/columns ``step`` apart): whether its grid cell is on."""
    rows = np.arange(0, shape[0] * step, step)[:shape[0]] // grid_size
    cols = np.arange(0, shape[1] * step, step)[:shape[1]] // grid_size
    return cells[np.ix_(rows, cols)] != 0


@pytest.mark.parametrize("step", [1, 2])
def test_matching_only_the_given_cells_gives_the_same_disparities_there(plants, rng, step):
    """Dense matching restricted to grid cells: the same disparities and offsets as the whole
    image in those cells, invalid elsewhere."""
    from canopy_stereo.elas.parallel import run_row_bands

    p = plants["params"]
    for right_image, sign in ((False, 1), (True, -1)):
        args = _match_args(plants["maps"][right_image], p, sign, step, True)
        full_d, full_o = matching.dense_match(*args)
        cells = rng.random(plants["maps"][right_image]["counts"].shape) < 0.5
        job, disp, off = matching.match_job(*args, cells=cells)
        run_row_bands(job)
        on = _cell_pixels(cells, p.grid_size, disp.shape, step)
        assert same_bits(disp[on], full_d[on]) and same_bits(off[on], full_o[on])
        assert (disp[~on] == INVALID).all() and (full_d[~on] >= 0).mean() > 0.3


def test_elas_run_with_match_cells(plants, rng, monkeypatch):
    """Every cell: the maps of the whole pair bit for bit. Some cells, filters off: the left
    map of the whole pair in those cells (the right map is matched wherever the left-right
    check reads it), invalid elsewhere. A grid of the wrong shape is refused."""
    from canopy_stereo.elas import core
    from canopy_stereo.errors import ImageError

    left, right = plants["left"], plants["right"]
    p = make_params("robotics", disp_min=0, disp_max=120)
    gh, gw = -(-left.shape[0] // p.grid_size), -(-left.shape[1] // p.grid_size)
    whole = elas_run(left, right, p, want_right=False)
    every = elas_run(left, right, p, want_right=False, match_cells=np.ones((gh, gw), bool))
    assert same_bits(every.disp_left, whole.disp_left)
    cells = rng.random((gh, gw)) < 0.4
    cells[:, -3:] = True                          # right-hand cells: partners far to the left
    # gap interpolation off (subsampled maps fill one-pixel gaps whatever ipol_gap_width says)
    monkeypatch.setattr(core, "interpolate_gaps", lambda disp, *args, **kwargs: disp)
    for subsampling in (False, True):
        raw = make_params("robotics", disp_min=0, disp_max=120, speckle_size=0, ipol_gap_width=0,
                          filter_adaptive_mean=False, filter_median=False, subsampling=subsampling)
        full = elas_run(left, right, raw, want_right=False).disp_left
        # want_right=False: the right map in its partners' cells; True: the swept cells
        for want_right in (False, True):
            some = elas_run(left, right, raw, want_right=want_right, match_cells=cells).disp_left
            on = _cell_pixels(cells, p.grid_size, some.shape, 2 if subsampling else 1)
            assert same_bits(some[on], full[on]) and (full[on] >= 0).mean() > 0.5
            assert (some[~on] == INVALID).all()
    with pytest.raises(ImageError, match="match_cells"):
        elas_run(left, right, p, match_cells=np.ones((gh + 1, gw), bool))


def test_partner_cells_are_the_cells_the_left_right_check_reads(plants, rng):
    """postprocess.partner_cells against its definition: the cell of round(u - d) for every
    valid left pixel (rows/columns ``step`` apart, rounding half up)."""
    g = 20
    for step in (1, 2):
        disp = random_disparity(rng, (240 // step, 320 // step), integer=True, hi=90, invalid=0.995)
        ref = np.zeros((12, 16), np.uint8)
        for r, c in zip(*np.nonzero(disp >= 0)):
            c2 = int(np.floor((c * step - disp[r, c]) / step + 0.5))
            if 0 <= c2 < disp.shape[1]:
                ref[(r * step) // g, (c2 * step) // g] = 1
        got = postprocess.partner_cells(disp, step=step, grid_size=g, image_size=(320, 240))
        assert same_bits(got, ref) and 0 < ref.mean() < 1
