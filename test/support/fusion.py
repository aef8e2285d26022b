"""Helpers of the fusion_node tests: clouds of curved patches, publishing one, waiting for the model
(test/ros/test_fusion_node.py, test/ros/test_node_limits.py)."""
from __future__ import annotations

import numpy as np

from canopy_stereo.ros.context import wait_for
from canopy_stereo.ros.convert import cloud2_to_points, points_to_cloud2

T0 = 1_700_000_000_000_000_000
TIMEOUT = 30.0


def patch_cloud_m(seed=0, n=10):
    """Curved patches about 0.65 m in front of the rig, metres, with colours."""
    rng = np.random.default_rng(seed)
    pts = []
    for _ in range(n):
        c = rng.uniform(-0.08, 0.08, 3) + [0, 0, 0.65]
        nrm = rng.normal(size=3)
        nrm /= np.linalg.norm(nrm)
        a = np.cross(nrm, [1.0, 0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(nrm, a)
        g = np.arange(-0.025, 0.025, 0.001)
        u, v = [x.ravel() for x in np.meshgrid(g, g)]
        k = u * u + v * v < 0.025 ** 2
        pts.append(c + u[k, None] * a + v[k, None] * b + 10.0 * (u[k] ** 2 + v[k] ** 2)[:, None] * nrm)
    pts = np.concatenate(pts)
    return pts, np.full((len(pts), 3), 120, np.uint8)


def send_cloud(pub, pts, cols, k):
    pub.publish(points_to_cloud2(pts, cols, stamp_ns=T0 + k * 100_000_000, frame_id="canopy_world",
                                 organized=False))


def latest_model(models, n_before):
    assert wait_for(lambda: len(models) > n_before, TIMEOUT), "no canopy_points published"
    return cloud2_to_points(models[-1])
