"""Procedural surface textures (albedo) as functions of the surface point.

Every texture is evaluated at 2-D texture coordinates ``(tu, tv)`` in
millimetres on the surface itself (leaf blade coordinates, unrolled cylinders, plane
coordinates; see :mod:`canopy_stereo.sim.raycast`), never at pixels, so both
cameras see exactly the same pattern at the same surface point and the colours
of a point agree between the views (Lambertian, no specular term).

A material is a kind (one of the ``MAT_*`` codes below), an integer seed and
up to :data:`N_MATERIAL_PARAMS` float parameters whose meaning depends on the
kind (see :data:`MATERIAL_PARAMS`; lengths in millimetres whatever the
world unit, so a scene looks the same in a rig in metres or millimetres).
Albedos are linear RGB in ``[0, 1]``.

The noise is hashed value noise (quintic interpolation of a per-lattice-point
hash), so it is deterministic, needs no tables and runs inside numba kernels.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

MAT_CROTON = 0
MAT_CITRUS = 1
MAT_SEEDLING = 2
MAT_STEM = 3
MAT_BARK = 4
MAT_POT = 5
MAT_SOIL = 6
MAT_BACKDROP = 7
MAT_FOLIAGE = 8
MAT_TRAY = 9
MAT_FRUIT = 10
MAT_CHECKERBOARD = 11
MAT_SHEET = 12
MAT_PLASTIC = 13
MAT_TINTED_LEAF = 14

#: Material name -> kind code.
MATERIAL_KINDS = {
    "croton": MAT_CROTON, "citrus": MAT_CITRUS, "seedling": MAT_SEEDLING, "stem": MAT_STEM,
    "bark": MAT_BARK, "pot": MAT_POT, "soil": MAT_SOIL, "backdrop": MAT_BACKDROP,
    "foliage": MAT_FOLIAGE, "tray": MAT_TRAY, "fruit": MAT_FRUIT,
    "checkerboard": MAT_CHECKERBOARD, "sheet": MAT_SHEET, "plastic": MAT_PLASTIC,
    "tinted_leaf": MAT_TINTED_LEAF,
}

#: Number of float parameters a material carries.
N_MATERIAL_PARAMS = 6

#: Meaning of the parameters of each material kind (in order; unlisted ones are unused).
MATERIAL_PARAMS = {
    "croton": ("age: 0 young green-yellow .. 1 old red-orange", "secondary vein count",
               "vein slant (tan of the angle to the midrib)", "brightness factor"),
    "citrus": ("age: 0 young light green .. 1 old dark green", "secondary vein count",
               "vein slant (tan of the angle to the midrib)", "brightness factor"),
    "seedling": ("age: 0 pale .. 1 dark green", "secondary vein count",
                 "vein slant (tan of the angle to the midrib)", "brightness factor"),
    "stem": ("greenness 0 brown .. 1 green",),
    "bark": (),
    "pot": ("height of the pot (mm, for the rim band)",),
    "soil": ("grain size (mm)",),
    "backdrop": ("pattern scale (mm)",),
    "foliage": ("blotch scale (mm)",),
    "tray": ("cell pitch (mm)", "wall half thickness (mm)",
             "grain size of the soil in the cells (mm)"),
    "fruit": (),
    "checkerboard": ("square side (mm)", "squares across", "squares down"),
    "plastic": ("red albedo 0..1", "green albedo 0..1", "blue albedo 0..1",
                "mottle amplitude 0..1 (default 0.08)", "mottle scale (mm, default 3)"),
    "tinted_leaf": ("red albedo 0..1", "green albedo 0..1", "blue albedo 0..1",
                    "secondary vein count", "variegation 0..1 (cream patches)",
                    "vein lightness 0..1 (light veins of silver or purple leaves)"),
    "sheet": ("grid spacing (mm)", "grid line width (mm)", "origin u (mm)", "origin v (mm)",
              "angle of the side lines (degrees)", "line width of the three lines (mm)"),
}


@njit(cache=True)
def _hash(ix, iy, seed):
    """Uniform [0, 1) hash of an integer lattice point and a seed."""
    h = (ix * 374761393 + iy * 668265263 + seed * 1442695041 + 1013904223) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = ((h ^ (h >> 16)) * 2246822519) & 0xFFFFFFFF
    h = h ^ (h >> 15)
    return h * (1.0 / 4294967296.0)


@njit(cache=True)
def _fade(t):
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0)


@njit(cache=True)
def value_noise(x, y, seed):
    """Smooth value noise in [0, 1] with unit lattice spacing."""
    fx = math.floor(x)
    fy = math.floor(y)
    ix = np.int64(fx)
    iy = np.int64(fy)
    tx = _fade(x - fx)
    ty = _fade(y - fy)
    a = _hash(ix, iy, seed)
    b = _hash(ix + 1, iy, seed)
    c = _hash(ix, iy + 1, seed)
    d = _hash(ix + 1, iy + 1, seed)
    top = a + (b - a) * tx
    bottom = c + (d - c) * tx
    return top + (bottom - top) * ty


@njit(cache=True)
def fbm(x, y, seed, octaves):
    """Fractal sum of ``octaves`` value-noise layers (halving amplitude), in [0, 1]."""
    total = 0.0
    amp = 1.0
    norm = 0.0
    freq = 1.0
    for o in range(octaves):
        total += amp * value_noise(x * freq + 17.3 * o, y * freq - 9.1 * o, seed + 101 * o)
        norm += amp
        amp *= 0.5
        freq *= 2.03
    return total / norm


@njit(cache=True)
def _smoothstep(e0, e1, x):
    t = (x - e0) / (e1 - e0)
    if t < 0.0:
        t = 0.0
    elif t > 1.0:
        t = 1.0
    return t * t * (3.0 - 2.0 * t)


@njit(cache=True)
def _mix(a, b, t):
    return a + (b - a) * t


@njit(cache=True)
def _leaf_veins(x, y, span, half_width, rel, n_veins, slant):
    """Vein masks of a blade: (midrib, secondary veins), each in [0, 1].

    ``x`` along the midrib from the base, ``y`` across (mm), ``rel``
    the position across the blade relative to the local half-width (0 on the
    midrib, 1 at the margin).
    """
    s = x / span
    ay = abs(y)
    mid_w = 0.35 + 0.022 * half_width * (1.0 - 0.6 * s)
    midrib = 1.0 - _smoothstep(0.55 * mid_w, mid_w, ay)
    spacing = span / n_veins
    # secondary veins leave the midrib towards the tip and bend towards the margin
    phase = (x - slant * ay * (1.0 - 0.3 * rel)) / spacing
    dist = abs(phase - math.floor(phase + 0.5)) * spacing / math.sqrt(1.0 + slant * slant)
    vein_w = (0.18 + 0.012 * half_width) * (1.0 - 0.6 * rel)
    sec = 1.0 - _smoothstep(0.5 * vein_w, vein_w, dist)
    sec *= _smoothstep(0.02, 0.12, rel) * (1.0 - _smoothstep(0.8, 0.97, rel))
    return midrib, sec


@njit(cache=True)
def _tinted_leaf(seed, params, x, y, span, half_width, rel):
    """A leaf of any colour (purple, silver, yellowing, variegated): base albedo
    ``params[0:3]``, lighter veins, optional cream variegation patches."""
    n_veins = max(params[3], 2.0)
    midrib, sec = _leaf_veins(x, y, span, half_width, rel, n_veins, 1.0)
    r, g, b = params[0], params[1], params[2]
    patch = _smoothstep(0.58, 0.66, fbm(x / 9.0, y / 9.0, seed + 71, 2)) * params[4]
    r = _mix(r, 0.62, patch)
    g = _mix(g, 0.60, patch)
    b = _mix(b, 0.38, patch)
    vein = max(midrib, 0.6 * sec) * (0.3 + 0.7 * params[5])
    r = _mix(r, min(1.0, r * 1.6 + 0.05), vein)
    g = _mix(g, min(1.0, g * 1.6 + 0.05), vein)
    b = _mix(b, min(1.0, b * 1.6 + 0.05), vein)
    fine = 0.75 + 0.5 * fbm(x / 1.3, y / 1.3, seed + 11, 2)
    mid = 0.8 + 0.4 * value_noise(x / 4.5, y / 4.5, seed + 23)
    shade = fine * mid
    return r * shade, g * shade, b * shade


@njit(cache=True)
def leaf_albedo(kind, seed, params, x, y, span, half_width, rel):
    """Linear RGB albedo of a leaf blade at blade coordinates ``(x, y)`` (mm)."""
    if kind == MAT_TINTED_LEAF:
        return _tinted_leaf(seed, params, x, y, span, half_width, rel)
    age = params[0]
    n_veins = max(params[1], 2.0)
    slant = params[2]
    bright = params[3] if params[3] > 0.0 else 1.0
    midrib, sec = _leaf_veins(x, y, span, half_width, rel, n_veins, slant)
    fine = 0.75 + 0.5 * fbm(x / 1.3, y / 1.3, seed + 11, 2)
    mid = 0.8 + 0.4 * value_noise(x / 4.5, y / 4.5, seed + 23)
    ridge = 1.0 - abs(2.0 * value_noise(x / 2.2 + 5.0, y / 2.2, seed + 31) - 1.0)
    net = ridge ** 6
    if kind == MAT_CROTON:
        # variegation: green ground with yellow / orange / red patches and veins
        patch = fbm(x / 16.0, y / 16.0, seed + 47, 2)
        warm_r = _mix(0.78, 0.60, age)
        warm_g = _mix(0.55, 0.10, age)
        warm_b = _mix(0.06, 0.03, age)
        t = _smoothstep(0.62 - 0.15 * age, 0.70 - 0.15 * age, patch)
        r = _mix(0.045, warm_r, t)
        g = _mix(0.150, warm_g, t)
        b = _mix(0.030, warm_b, t)
        vein = max(midrib, 0.85 * sec)
        vr = _mix(0.85, 0.75, age)
        vg = _mix(0.65, 0.28, age)
        r = _mix(r, vr, vein)
        g = _mix(g, vg, vein)
        b = _mix(b, 0.05, vein)
        rim = _smoothstep(0.88, 1.0, rel) * (1.0 - age)
        r = _mix(r, 0.75, 0.6 * rim)
        g = _mix(g, 0.60, 0.6 * rim)
    else:
        if kind == MAT_CITRUS:
            r = _mix(0.075, 0.030, age)
            g = _mix(0.240, 0.120, age)
            b = _mix(0.035, 0.020, age)
        else:  # seedling
            r = _mix(0.140, 0.060, age)
            g = _mix(0.360, 0.220, age)
            b = _mix(0.060, 0.030, age)
        vein = max(midrib, 0.6 * sec)
        r = _mix(r, r * 2.6 + 0.04, vein)
        g = _mix(g, g * 1.6 + 0.03, vein)
        b = _mix(b, b * 1.5, vein)
        # oil glands / stomata clusters: small lighter dots
        dots = _smoothstep(0.70, 0.80, value_noise(x / 0.9, y / 0.9, seed + 59))
        r *= 1.0 + 0.5 * dots
        g *= 1.0 + 0.35 * dots
    shade = bright * fine * mid * (1.0 + 0.35 * net)
    return r * shade, g * shade, b * shade


@njit(cache=True)
def _soil(tu, tv, grain, seed):
    """Dark granular soil with light pebbles; ``grain`` in mm."""
    n = fbm(tu / grain, tv / grain, seed, 2)
    big = 2.5 * grain
    pebble = _smoothstep(0.72, 0.82, value_noise(tu / big, tv / big, seed + 9))
    k = 0.45 + 1.1 * n
    return (_mix(0.075 * k, 0.28, pebble), _mix(0.050 * k, 0.23, pebble),
            _mix(0.030 * k, 0.17, pebble))


@njit(cache=True)
def albedo(kind, seed, params, tu, tv, geom, rel, mm_per_unit):
    """Linear RGB albedo of any material at texture coordinates ``(tu, tv)`` (mm).

    ``geom`` is the primitive's geometry row in world units (leaves need their
    span and half-width), ``mm_per_unit`` converts it to millimetres; ``rel``
    is the relative position across a leaf blade.
    """
    if kind <= MAT_SEEDLING or kind == MAT_TINTED_LEAF:
        return leaf_albedo(kind, seed, params, tu, tv, geom[0] * mm_per_unit,
                           geom[1] * mm_per_unit, rel)
    if kind == MAT_STEM:
        streak = fbm(tu / 0.7, tv / 6.0, seed, 2)
        grain = 0.8 + 0.4 * value_noise(tu / 0.8, tv / 0.8, seed + 5)
        green = params[0]
        r = _mix(0.16, 0.08, green) * (0.7 + 0.6 * streak) * grain
        g = _mix(0.11, 0.20, green) * (0.7 + 0.6 * streak) * grain
        b = _mix(0.06, 0.04, green) * (0.7 + 0.6 * streak) * grain
        return r, g, b
    if kind == MAT_BARK:
        streak = fbm(tu / 0.8, tv / 5.0, seed, 3)
        lent = _smoothstep(0.78, 0.86, value_noise(tu / 1.1, tv / 2.5, seed + 3))
        k = (0.6 + 0.8 * streak) * (1.0 + 0.8 * lent)
        return 0.13 * k, 0.10 * k, 0.065 * k
    if kind == MAT_POT:
        n = fbm(tu / 2.0, tv / 2.0, seed, 3)
        blotch = value_noise(tu / 14.0, tv / 14.0, seed + 7)
        k = (0.75 + 0.5 * n) * (0.85 + 0.3 * blotch)
        height = params[0]
        band = 1.0
        if height > 0.0 and tv > height - 0.12 * height:
            band = 0.8
        return 0.48 * k * band, 0.17 * k * band, 0.075 * k * band
    if kind == MAT_SOIL:
        return _soil(tu, tv, params[0] if params[0] > 0.0 else 1.0, seed)
    if kind == MAT_BACKDROP:
        scale = params[0] if params[0] > 0.0 else 3.0
        n1 = fbm(tu / scale, tv / scale, seed, 3)
        n2 = value_noise(tu / (5.0 * scale), tv / (5.0 * scale), seed + 13)
        k = (0.45 + 1.1 * n1) * (0.7 + 0.6 * n2)
        return 0.30 * k, 0.31 * k, 0.34 * k
    if kind == MAT_FOLIAGE:
        scale = params[0] if params[0] > 0.0 else 40.0
        blob = fbm(tu / scale, tv / scale, seed, 3)
        fine = 0.6 + 0.8 * fbm(tu / 4.0, tv / 4.0, seed + 17, 2)
        sky = _smoothstep(0.62, 0.70, blob)
        r = _mix(0.030 * fine, 0.45 + 0.1 * fine, sky)
        g = _mix(0.085 * fine, 0.55 + 0.1 * fine, sky)
        b = _mix(0.020 * fine, 0.70 + 0.1 * fine, sky)
        return r, g, b
    if kind == MAT_TRAY:
        pitch = params[0]
        wall = params[1]
        grain = params[2] if params[2] > 0.0 else 1.0
        fu = tu / pitch - math.floor(tu / pitch)
        fv = tv / pitch - math.floor(tv / pitch)
        edge = min(min(fu, 1.0 - fu), min(fv, 1.0 - fv)) * pitch
        is_wall = 1.0 - _smoothstep(wall * 0.8, wall * 1.2, edge)
        r, g, b = _soil(tu, tv, grain, seed)
        plastic = 0.025 * (0.7 + 0.6 * value_noise(tu / 1.5, tv / 1.5, seed + 21))
        return _mix(r, plastic, is_wall), _mix(g, plastic, is_wall), _mix(b, plastic * 1.1, is_wall)
    if kind == MAT_PLASTIC:
        amp = params[3] if params[3] > 0.0 else 0.08
        scale = params[4] if params[4] > 0.0 else 3.0
        k = 1.0 + amp * (2.0 * fbm(tu / scale, tv / scale, seed, 3) - 1.0)
        return params[0] * k, params[1] * k, params[2] * k
    if kind == MAT_CHECKERBOARD:
        # squares of side params[0] mm, params[1] x params[2] of them centred on the
        # plane's origin, the first one black; white margin around them
        sq = params[0]
        i = math.floor(tu / sq + 0.5 * params[1])
        j = math.floor(tv / sq + 0.5 * params[2])
        if i < 0 or j < 0 or i >= params[1] or j >= params[2] or (i + j) % 2 == 1:
            return 0.80, 0.80, 0.78
        return 0.035, 0.035, 0.035
    if kind == MAT_SHEET:
        # white A0 paper: a light grid every params[0] mm and three dark lines from
        # the origin (params[2], params[3]) along +v and turned by +-params[4] degrees
        grid = params[0]
        half = 0.5 * params[1]
        fu = tu / grid - math.floor(tu / grid)
        fv = tv / grid - math.floor(tv / grid)
        r = 0.78
        if min(fu, 1.0 - fu) * grid < half or min(fv, 1.0 - fv) * grid < half:
            r = 0.55
        du = tu - params[2]
        dv = tv - params[3]
        for k in range(3):
            a = math.radians(params[4]) * (k - 1)
            along = du * math.sin(a) + dv * math.cos(a)
            across = du * math.cos(a) - dv * math.sin(a)
            if along >= 0.0 and abs(across) < 0.5 * params[5]:
                r = 0.08
        return r, r, 0.97 * r
    # fruit
    dimple = fbm(tu / 1.0, tv / 1.0, seed, 2)
    k = 0.8 + 0.4 * dimple
    return 0.70 * k, 0.28 * k, 0.025 * k
