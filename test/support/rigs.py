"""Rigs the geometry and frame tests share (beside config/*.yaml and the ``paper_rig`` fixture)."""
from __future__ import annotations

import numpy as np

from canopy_stereo.geometry.camera import compose_projection
from canopy_stereo.io.rig import Rig


def _rot_y(deg):
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def unequal_verged_rig() -> Rig:
    """Two cameras 40 mm apart, each turned 2 degrees towards the other, with principal
    points 55 px (x) and 20 px (y) apart and different focal lengths; world = mm."""
    K1 = np.array([[640.0, 0, 345.0], [0, 642.0, 250.0], [0, 0, 1]])
    K2 = np.array([[652.0, 0, 290.0], [0, 650.0, 230.0], [0, 0, 1]])
    R1 = _rot_y(-2.0)   # rows = camera axes; the left camera turns towards +x
    R2 = _rot_y(2.0)
    return Rig(P_left=compose_projection(K1, R1, [0.0, 0.0, 0.0]),
               P_right=compose_projection(K2, R2, [40.0, 0.0, 0.0]), image_size=(640, 480),
               world_unit="mm")
