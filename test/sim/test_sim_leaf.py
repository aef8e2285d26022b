"""Leaf blade geometry of the simulator: outline, arc lengths, area, exact sizes."""
import numpy as np
import pytest

from canopy_stereo.sim import Leaf, Material
from canopy_stereo.sim import leaf as leafgeom

CROTON = Material("croton", 1, (0.5, 12, 1.2, 1.0))


def polyline_length(points):
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def test_outline_is_widest_at_peak_and_closed_at_ends():
    a, b, hw = 0.62, 0.85, 48.0
    s = np.linspace(0, 1, 20001)
    w = leafgeom.half_width_at(s, hw, a, b)
    assert w[0] == 0 and w[-1] == 0
    assert w.max() == pytest.approx(hw, rel=1e-6)
    assert s[np.argmax(w)] == pytest.approx(a / (a + b), abs=1e-4)


@pytest.mark.parametrize("droop, rise", [(0.0, 0.0), (-0.0009, 0.1), (0.002, -0.05)])
def test_midrib_arc_length_matches_polyline(droop, rise):
    span = 150.0
    x = np.linspace(0, span, 200001)
    pts = np.column_stack([x, droop * x * x + rise * x])
    expected = polyline_length(pts)
    assert leafgeom.midrib_length(span, droop, rise) == pytest.approx(expected, rel=1e-9)


def test_leaf_built_with_exact_true_dimensions():
    lf = Leaf.with_dimensions(1, [0, 0, 600], [-1, 0, 0], [0, 0, -1], 160.0, 97.0, CROTON,
                              droop=-0.0009, rise=0.1, cup=0.0016)
    assert lf.length == pytest.approx(160.0, abs=1e-9)
    assert lf.width == pytest.approx(97.0, abs=1e-9)
    # the curved blade is shorter as the crow flies than along its surface
    assert lf.length_chord < lf.length
    assert lf.width_chord < lf.width
    assert lf.length_chord == pytest.approx(np.linalg.norm(lf.tip - lf.base))
    # the width endpoints lie on the widest cross-section, across the midrib
    w0, w1 = lf.width_endpoints()
    assert np.linalg.norm(w1 - w0) == pytest.approx(lf.width_chord)
    midrib_dir = lf.axes[0]
    assert abs((w1 - w0) @ midrib_dir) < 1e-9


def test_area_of_flat_ellipse_and_curved_blade():
    # a = b = 0.5 is an ellipse with semi-axes span/2 and half_width
    assert leafgeom.surface_area(100.0, 20.0, 0.5, 0.5, 0, 0, 0) == pytest.approx(np.pi * 50 * 20,
                                                                                  rel=1e-9)
    # curved blade: compare with a fine triangulation of the surface
    span, hw, a, b, kx, gx, ky = 140.0, 40.0, 0.6, 0.8, -0.001, 0.12, 0.003
    area = leafgeom.surface_area(span, hw, a, b, kx, gx, ky)
    s = 0.5 * (1 - np.cos(np.linspace(0, np.pi, 1201)))
    rel = np.linspace(-1, 1, 401)
    x = s[:, None] * span * np.ones_like(rel)[None, :]
    y = leafgeom.half_width_at(s, hw, a, b)[:, None] * rel[None, :]
    z = leafgeom.surface_height(x, y, kx, gx, ky)
    P = np.stack([x, y, z], axis=-1)
    d1 = P[1:, 1:] - P[:-1, :-1]
    d2 = P[1:, :-1] - P[:-1, 1:]
    mesh_area = 0.5 * np.linalg.norm(np.cross(d1, d2), axis=-1).sum()
    assert area == pytest.approx(mesh_area, rel=2e-3)
    flat = leafgeom.surface_area(span, hw, a, b, 0, 0, 0)
    assert area > flat


def test_surface_points_lie_on_the_blade():
    lf = Leaf.with_dimensions(3, [10, -20, 650], [1, -0.2, -0.3], [0.2, -0.3, -1], 120.0, 60.0,
                              CROTON, droop=-0.002, rise=0.2, cup=0.004)
    pts = lf.surface_points(40, 11)
    local = (pts - lf.base) @ lf.axes.T
    z = leafgeom.surface_height(local[:, 0], local[:, 1], lf.droop, lf.rise, lf.cup)
    assert np.allclose(local[:, 2], z, atol=1e-9)
    hw = leafgeom.half_width_at(local[:, 0] / lf.span, lf.half_width, lf.base_exponent,
                                lf.tip_exponent)
    assert np.all(np.abs(local[:, 1]) <= hw + 1e-9)
