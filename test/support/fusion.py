"""Helpers of the fusion tests: clouds of curved patches (``canopy-stereo fuse``'s
test/cli/test_fuse.py, in mm), publishing one, waiting for the model (test/ros/test_fusion_node.py,
test/ros/test_node_limits.py, in metres)."""
from __future__ import annotations

import numpy as np

T0 = 1_700_000_000_000_000_000
TIMEOUT = 30.0

#: The patches' layout in each unit (written out, so that each unit's points stay exactly as they were):
#: centres spread +-``spread`` about ``depth`` in front of the rig, discs of radius ``half`` sampled at
#: ``step``, bent by ``bend`` * r^2 along their normal.
_LAYOUT = {"mm": {"spread": 80.0, "depth": 650.0, "half": 25.0, "step": 1.0, "bend": 0.01},
           "m": {"spread": 0.08, "depth": 0.65, "half": 0.025, "step": 0.001, "bend": 10.0}}


def patch_points(seed=0, n=10, *, unit="mm") -> np.ndarray:
    """(N, 3) points of ``n`` curved disc patches about 650 mm in front of a rig, in ``unit``
    (``"mm"`` or ``"m"``)."""
    lay = _LAYOUT[unit]
    rng = np.random.default_rng(seed)
    pts = []
    for _ in range(n):
        c = rng.uniform(-lay["spread"], lay["spread"], 3) + [0, 0, lay["depth"]]
        nrm = rng.normal(size=3)
        nrm /= np.linalg.norm(nrm)
        a = np.cross(nrm, [1.0, 0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(nrm, a)
        g = np.arange(-lay["half"], lay["half"], lay["step"])
        u, v = [x.ravel() for x in np.meshgrid(g, g)]
        k = u * u + v * v < lay["half"] ** 2
        pts.append(c + u[k, None] * a + v[k, None] * b + lay["bend"] * (u[k] ** 2 + v[k] ** 2)[:, None] * nrm)
    return np.concatenate(pts)


def patch_cloud_m(seed=0, n=10):
    """Curved patches about 0.65 m in front of the rig, metres, with colours (grey 120)."""
    pts = patch_points(seed, n, unit="m")
    return pts, np.full((len(pts), 3), 120, np.uint8)


def send_cloud(pub, pts, cols, k):
    from canopy_stereo.ros.convert import points_to_cloud2

    pub.publish(points_to_cloud2(pts, cols, stamp_ns=T0 + k * 100_000_000, frame_id="canopy_world",
                                 organized=False))


def latest_model(models, n_before):
    from canopy_stereo.ros.context import wait_for
    from canopy_stereo.ros.convert import cloud2_to_points

    assert wait_for(lambda: len(models) > n_before, TIMEOUT), "no canopy_points published"
    return cloud2_to_points(models[-1])
