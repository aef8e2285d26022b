"""Two rigs on one robot: two ``canopy_graph`` processes at once on one DDS domain.

Rig A and rig B play the bundled croton bag (recorded under ``/stereo``) into their own
namespaces ``rig_a`` and ``rig_b`` (``--namespace`` + ``--frame-prefix``), mounted on a common
``base_link`` with different ``--mount`` transforms, each recording its outputs. Checked:

* the union of the two recordings' ``/tf_static`` is one tree rooted at ``base_link`` in
  which no frame appears twice;
* each recording holds only its own rig's topics (and ``/tf_static``);
* both graphs ran side by side: every node exists once per namespace and ``/diagnostics``
  has distinct status names per rig;
* the same input frames, transformed to ``base_link`` with each recording's transforms,
  differ between the rigs by exactly the difference of the mounts (< 1 mm).

Deterministic on a loaded machine: the graphs play the bag in a loop (``--loop``) until the
test's probe has matched both graphs' ``/diagnostics`` publishers and received a report from
every node of both rigs while both ran, and each graph has completed a whole pass; only then
are they stopped (SIGINT: the frames in flight are awaited and the recordings closed). A
single short pass could end before DDS discovery matched the probe (seconds under load).
The recordings are compared on each stamp's first cloud (the first pass).
"""
from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("rclpy")

from canopy_stereo.geometry.frames import pose_values  # noqa: E402
from canopy_stereo.geometry.tf_buffer import TransformBuffer  # noqa: E402
from canopy_stereo.geometry.transforms import make_transform, rotation_about_axis, transform_points  # noqa: E402
from test.support.ros_harness import REPO, Probe, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

MOUNTS = {
    "rig_a": make_transform(rotation_about_axis([0.0, 0.0, 1.0], np.radians(30.0)), [0.40, 0.25, 1.10]),
    "rig_b": make_transform(rotation_about_axis([0.3, 0.0, 1.0], np.radians(-40.0)), [0.40, -0.25, 0.95]),
}


def _recorded(path):
    """``(topics, static transforms [(parent, child, T)], points2 by stamp (its first cloud: the
    first pass of a looped bag), frames of points2)``."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.convert import cloud2_to_points, stamp_to_ns
    from canopy_stereo.ros.tf import parse_tf_message

    bag = BagReader(path)
    static = [(p, c, T) for m in bag.messages(["/tf_static"]) for _, p, c, T in parse_tf_message(m.data)]
    clouds, frames = {}, set()
    for name in bag.topics:
        if name.endswith("/points2"):
            for _, msg in bag.read([name]):
                stamp = stamp_to_ns(msg.header.stamp)
                if stamp not in clouds:
                    clouds[stamp] = cloud2_to_points(msg)[0].astype(np.float64)
                frames.add(msg.header.frame_id)
    return set(bag.topics), static, clouds, frames


NODES = ("rectify_node", "disparity_node", "point_cloud_node")


def _statuses(diagnostics):
    """``[(arrival s, DiagnosticStatus)]`` of every /diagnostics message received so far."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message

    with diagnostics.lock:
        items = list(diagnostics.items)
    return [(t, st) for t, _, d in items for st in deserialize_message(d, DiagnosticArray).status]


def _side_by_side(statuses) -> bool:
    """Every node of both rigs reported, and each rig reported after the other's first report."""
    ids = {st.hardware_id for _, st in statuses}
    if not all({f"/rig_a/{node}", f"/rig_b/{node}"} <= ids for node in NODES):
        return False
    spans = {ns: [t for t, st in statuses if st.hardware_id.startswith(f"/{ns}/")] for ns in MOUNTS}
    return max(min(v) for v in spans.values()) < min(max(v) for v in spans.values())


def test_two_rigs_side_by_side_on_one_robot(ros_processes, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray

    group = ros_processes
    rig, bag = REPO / "config" / "croton_rig.yaml", REPO / "bags" / "croton.mcap"
    probe = Probe(group.domain_id, namespace="/")
    try:
        diagnostics = probe.subscribe(DiagnosticArray, "/diagnostics")
        graphs = {
            ns: group.start("canopy_graph", "--rig", rig, "--bag", bag, "--rate", "0", "--loop", "--namespace", ns,
                            "--frame-prefix", f"{ns}/", "--parent-frame", "base_link",
                            "--mount", *pose_values(T), "--record", tmp_path / f"{ns}.mcap",
                            ros_args=["-p", "diagnostic_period:=0.2"])
            for ns, T in MOUNTS.items()}

        def seen_and_recorded() -> bool:  # the probe heard both rigs at once; each played the bag once
            return (all(re.search(r"\(after pass [1-9]", g.log()) for g in graphs.values())
                    and _side_by_side(_statuses(diagnostics)))

        assert wait_for(seen_and_recorded, 240.0, poll_s=0.2, group=group), (
            sorted({st.hardware_id for _, st in _statuses(diagnostics)}), group.logs())
        codes = {ns: g.stop(timeout_s=60.0) for ns, g in graphs.items()}
        statuses = _statuses(diagnostics)
    finally:
        probe.close()
    assert codes == {"rig_a": 0, "rig_b": 0}, group.logs()
    # both graphs ran at once, every node once per namespace, no status name shared
    assert _side_by_side(statuses), "not side by side"
    names = {st.name for _, st in statuses}
    assert {"rig_a/rectify_node: pipeline", "rig_b/rectify_node: pipeline"} <= names, sorted(names)
    assert not any(n.startswith("rectify_node") for n in names)

    rec = {ns: _recorded(tmp_path / f"{ns}.mcap") for ns in MOUNTS}
    # each recording: only its own rig's topics
    for ns, (topics, _, clouds, frames) in rec.items():
        assert topics - {"/tf_static"} and all(t.startswith(f"/{ns}/") for t in topics - {"/tf_static"}), topics
        assert f"/{ns}/points2" in topics and len(clouds) == 4 and frames == {f"{ns}/canopy_world"}, (
            sorted(topics), len(clouds), frames, group.logs())
    # the union of /tf_static: one tree, no frame twice, rooted at base_link
    union = rec["rig_a"][1] + rec["rig_b"][1]
    children = [c for _, c, _ in union]
    assert len(children) == len(set(children)), sorted(children)
    buf = TransformBuffer()
    for p, c, T in union:
        buf.set_transform(p, c, T, 0, static=True)
    roots = {f for f in buf.frames() if buf.parent(f) is None}
    assert roots == {"base_link"}
    assert {"rig_a/canopy_world", "rig_b/left_camera_rect_optical_frame"} <= buf.frames()
    # the same frames in base_link differ by the mounts' difference
    a_clouds, b_clouds = rec["rig_a"][2], rec["rig_b"][2]
    assert set(a_clouds) == set(b_clouds)
    T_a = buf.lookup("base_link", "rig_a/canopy_world")
    T_b = buf.lookup("base_link", "rig_b/canopy_world")
    difference = MOUNTS["rig_b"] @ np.linalg.inv(MOUNTS["rig_a"])
    worst = 0.0
    for stamp, pa in a_clouds.items():
        pb = b_clouds[stamp]
        assert pa.shape == pb.shape and len(pa) > 10000
        qa, qb = transform_points(T_a, pa), transform_points(T_b, pb)
        worst = max(worst, float(np.linalg.norm(transform_points(difference, qa) - qb, axis=1).max()))
    print(f"largest disagreement with the mount difference: {worst * 1e3:.2e} mm")
    assert worst < 0.001
