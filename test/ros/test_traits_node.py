"""``traits_node``: live traits of the croton bag equal ``canopy-stereo reconstruct --measure``.

rectify_node, disparity_node and traits_node run in processes of their own; a stand-in driver
publishes pairs of the bundled croton bag; a foreign subscriber reads ``traits``
(std_msgs/String JSON) and ``traits/markers`` (visualization_msgs/MarkerArray). The CLI
measures the same pairs (PNG files, as a user has them): the reports agree number for
number.
"""
from __future__ import annotations

import json
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from rclpy.serialization import deserialize_message  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from test.support.ros_harness import REPO, Probe, croton_frames, feed_pairs, wait_for  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

RIG = REPO / "config" / "croton_rig.yaml"
T0 = 1_760_000_000_000_000_000


def _numbers(report: dict) -> dict:
    """The measured numbers of a report: canopy scalars and per-leaf scalars."""
    out = {f"canopy.{k}": v for k, v in report["canopy"].items() if isinstance(v, (int, float))}
    for leaf in report["leaves"]:
        out.update({f"leaf{leaf['id']}.{k}": v for k, v in leaf.items() if isinstance(v, (int, float))})
    return out


def test_live_traits_equal_reconstruct_measure(ros_processes, tmp_path, cli):
    from canopy_stereo.io.images import write_image

    group = ros_processes
    group.start_graph(RIG, nodes=("rectify_node", "disparity_node"))
    group.start("traits_node", params_files=[RIG], params={"max_rate": 0.0})
    frames = croton_frames()[:2]  # two of the bag's four pairs: the CLI's measurement is the slow part
    probe = Probe(group.domain_id)
    try:
        left, right = probe.publisher(Image, "left/image_raw"), probe.publisher(Image, "right/image_raw")
        traits = probe.subscribe(String, "traits")
        markers = probe.subscribe(MarkerArray, "traits/markers")
        assert wait_for(lambda: traits.subscription.get_publisher_count() >= 1
                        and left.get_subscription_count() >= 1 and right.get_subscription_count() >= 1,
                        60.0, group=group), group.logs()
        # warm-up (every node subscribed and compiled): a pair, then wait, until a trait comes out
        warm = T0 - 100 * 10**9
        deadline = time.monotonic() + 120.0
        while len(traits) == 0 and time.monotonic() < deadline:
            feed_pairs(left, right, frames[:1], [warm], 1.0, right_offset_ns=0)
            warm += 10**9
            wait_for(lambda: len(traits) > 0, 5.0, group=group)
        assert len(traits) > 0, group.logs()
        stamps = [T0 + k * 1_000_000_000 for k in range(len(frames))]
        feed_pairs(left, right, frames, stamps, 0.5, right_offset_ns=0)  # one pair every 2 s

        def received() -> dict:  # stamp -> traits JSON (a String has no header: the JSON's stamp)
            with traits.lock:
                texts = [json.loads(deserialize_message(d, String).data) for _, _, d in traits.items]
            return {t["stamp"]["sec"] * 10**9 + t["stamp"]["nanosec"]: t for t in texts}

        assert wait_for(lambda: set(stamps) <= set(received()), 120.0, group=group), group.logs()
        live = received()

        def marker_arrays() -> dict:  # stamp -> MarkerArray (its markers' header stamp)
            with markers.lock:
                arrays = [deserialize_message(d, MarkerArray) for _, _, d in markers.items]
            return {a.markers[0].header.stamp.sec * 10**9 + a.markers[0].header.stamp.nanosec: a
                    for a in arrays if a.markers}

        assert wait_for(lambda: set(stamps) <= set(marker_arrays()), 10.0, group=group)
        boxes = [a for s, a in marker_arrays().items() if s in stamps]
    finally:
        probe.close()
    assert set(stamps) <= set(live)
    for k, (l_img, r_img) in enumerate(frames):
        write_image(tmp_path / f"l{k}.png", l_img)
        write_image(tmp_path / f"r{k}.png", r_img)
        code, out, err = cli("reconstruct", tmp_path / f"l{k}.png", tmp_path / f"r{k}.png", "--rig", RIG,
                             "-o", tmp_path / f"c{k}.ply", "--measure", "--report", tmp_path / f"r{k}.json")
        assert code == 0, err
        want = json.loads((tmp_path / f"r{k}.json").read_text())
        got = live[stamps[k]]
        assert got["format"] == 1 and got["frame_id"] == "canopy_world"
        assert got["stamp"] == {"sec": stamps[k] // 10**9, "nanosec": 0}
        a, b = _numbers(got["report"]), _numbers(want)
        assert set(a) == set(b) and len(got["report"]["leaves"]) == len(want["leaves"]) > 0
        for key, value in b.items():
            assert a[key] == pytest.approx(value, rel=1e-6, abs=1e-9), key
    # markers: a box and a label per plant, in the world frame, around the measured plant
    for arr in boxes:
        kinds = [m.type for m in arr.markers if m.action == Marker.ADD]
        assert arr.markers[0].action == Marker.DELETEALL and Marker.CUBE in kinds and Marker.TEXT_VIEW_FACING in kinds
        cube = next(m for m in arr.markers if m.type == Marker.CUBE)
        assert cube.header.frame_id == "canopy_world" and 0.4 < cube.pose.position.z < 1.2
        assert np.all(np.array([cube.scale.x, cube.scale.y, cube.scale.z]) > 0.05)
