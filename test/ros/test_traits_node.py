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


def test_a_plant_that_cannot_be_measured_does_not_drop_the_frame(harness, paper_rig):
    """In-process: the simulated seedling tray (320x240) has seedlings in the band along the
    left border the right camera does not see (no 3D point on them). The frame is measured
    and published all the same: those plants carry their reason, the others their numbers,
    the report counts them, and the node counts and warns them."""
    from stereo_msgs.msg import DisparityImage

    from canopy_stereo.pipeline.reconstruct import reconstruct_pair
    from canopy_stereo.ros import convert
    from canopy_stereo.ros.context import wait_for as ros_wait_for
    from canopy_stereo.ros.nodes.traits import TraitsNode
    from canopy_stereo.sim import render_scene, rig_at_resolution
    from test.support.nodes import node_kwargs

    tray = render_scene("seedling_tray", rig_at_resolution(paper_rig, 0.5))
    rec = reconstruct_pair(tray.left, tray.right, tray.rig)  # disparity_node's output for the pair
    node = harness.add(TraitsNode(**node_kwargs(harness, tray.rig, max_rate=0.0)))
    traits, markers = harness.collect(String, "traits"), harness.collect(MarkerArray, "traits/markers")
    pub_image, pub_disp = harness.publisher(Image, "left/image_raw"), harness.publisher(DisparityImage, "disparity")
    harness.connect(pub_image, pub_disp)
    rect = rec.rectification
    pub_disp.publish(convert.disparity_to_msg(rec.disparity, rect.focal_length, rect.baseline * 1e-3, 0.0,
                                              float(np.nanmax(rec.disparity)) + 1.0, stamp_ns=T0, doffs=rect.doffs))
    pub_image.publish(convert.image_to_msg(tray.left, "bgr8", stamp_ns=T0))
    assert ros_wait_for(lambda: len(traits) == 1 and len(markers) == 1, 120.0), dict(node.drops)
    report = json.loads(traits[0].data)["report"]
    failed = [p for p in report["plants"] if p["error"] is not None]
    ok = [p for p in report["plants"] if p["error"] is None]
    assert failed and len(ok) > 20 and report["n_plants_not_measured"] == len(failed)
    assert report["n_plants"] == len(report["plants"])
    for p in failed:
        assert "0 valid 3D points" in p["error"] and p["canopy"] is None
    for p in ok:
        assert p["canopy"]["height"] > 0 and p["canopy"]["hull_volume"] > 0
    assert node.counts["frames_measured"] == 1 and node.counts["plants_not_measured"] == len(failed)
    assert any(key.startswith("plant: plant not measured: ") for key in node.warnings)
    # a box and a label per plant with points (the failed ones have none)
    cubes = [m for m in markers[0].markers if m.type == Marker.CUBE]
    labels = [m.text for m in markers[0].markers if m.type == Marker.TEXT_VIEW_FACING]
    assert len(cubes) == len(labels) == len(ok)


def test_markers_label_a_plant_not_measured_with_its_reason():
    from canopy_stereo.measure.plant import PlantMeasurement, plant_summary
    from canopy_stereo.ros.nodes.traits import traits_markers

    pts = np.full((4, 6, 3), np.nan)
    pts[:, :3] = [100.0, 0.0, 800.0]
    pts[:, 3:] = [300.0, 50.0, 900.0]
    instances = np.zeros((4, 6), np.int32)
    instances[:, :3], instances[:, 3:] = 1, 2
    canopy = {"height": 120.0, "width": 80.0, "hull_volume": 250.0}
    plants = [plant_summary({"plant_index": 1, "canopy": canopy, "leaves": []}),
              plant_summary({"plant_index": 2, "error": "the reason", "at_image_border": False})]
    measured = PlantMeasurement(report={"plants": plants}, scene=None, mask=instances > 0, mask_source="automatic",
                                organized_mm=pts, instances=instances)
    labels = [m.text for m in traits_markers(measured, T0, "canopy_world").markers
              if m.type == Marker.TEXT_VIEW_FACING]
    assert labels == ["plant 1: height 120 mm, width 80 mm\nhull 250 cm^3, 0 leaves",
                      "plant 2: not measured\nthe reason"]
