"""Analytic scenes with exact answers for the measuring tests (test/measure, test/cli/test_measure.py)."""
from __future__ import annotations

import numpy as np

from canopy_stereo.geometry.camera import camera_centre, pixel_rays
from canopy_stereo.measure.analytic import EllipticLeaf, Plane, render


def leaf_in_view(P, pixel, dist, theta_deg, normal, a=80.0, b=48.5, **kw):
    """An elliptic leaf ``dist`` along the ray of ``pixel`` of camera ``P``, turned ``theta_deg``
    in its plane of normal ``normal``; semi-axes ``a``, ``b`` (world units)."""
    centre = camera_centre(P) + dist * pixel_rays(P, [pixel])[0]
    th = np.radians(theta_deg)
    return EllipticLeaf(centre=centre, length_dir=[np.cos(th), np.sin(th), 0.2], normal=normal,
                        a=a, b=b, **kw)


def two_leaf_scene(rig):
    """Two leaves standing over a floor, seen by the paper's left camera."""
    P = rig.P_left
    C = camera_centre(P)
    leaf_a = leaf_in_view(P, (220, 200), 420.0, 15.0, [0.1, -0.3, -1.0], a=60.0, b=35.0)
    leaf_b = leaf_in_view(P, (430, 260), 470.0, -40.0, [-0.2, -0.2, -1.0], a=55.0, b=30.0)
    floor = Plane(C + [0.0, 160.0, 0.0], [0.0, -1.0, 0.0])  # world +y is image-down
    wall = Plane(C + [0.0, 0.0, 900.0], [0.0, 0.0, 1.0])
    org, lab = render(P, rig.image_size, [leaf_a, leaf_b, floor, wall])
    return org, lab, (leaf_a, leaf_b)
