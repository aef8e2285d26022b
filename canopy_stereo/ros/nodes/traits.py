"""``traits_node``: the plant's traits, live, with the CLI's numbers.

Subscribes ``left/image_raw`` (the camera's raw left image, as the driver publishes it) and
``disparity`` (``stereo_msgs/DisparityImage`` of ``disparity_node``, stamped with the left
image's stamp), pairs them by exact stamp and measures the frame with the package's one
measuring pipeline (:func:`canopy_stereo.ros.measuring.measure_graph_frame`, i.e.
:func:`canopy_stereo.measure.plant.measure_plant`: automatic plant mask, plants, leaves,
canopy, one unit set), the function ``canopy-stereo reconstruct --measure`` and ``batch``
call, so a frame gives the same numbers here as there. At most ``max_rate`` frames per second are
measured (a measurement takes about a second on two cores); the others are counted as
skipped in ``/diagnostics``.

Publishes, stamped with the frame's stamp (readable without this package):

* ``traits`` (``std_msgs/String``): JSON ``{"format": 1, "stamp": {"sec", "nanosec"},
  "frame_id": <world frame of the points>, "report": REPORT}`` where REPORT is exactly the
  REPORT.json of ``canopy-stereo reconstruct --measure`` (``units``: lengths mm, areas
  cm^2, volumes cm^3; ``canopy``: height, width, depth, hull and voxel volumes, ...;
  ``leaves``: per leaf id, length, width, area, ...; ``source``: how it was measured);
* ``traits/markers`` (``visualization_msgs/MarkerArray``, for RViz and Foxglove): a
  DELETEALL, then per measured plant (``report["plants"]``) a translucent box around its
  points (axis-aligned in ``frame_id``, metres) and a text label with its index, height,
  width, hull volume and leaf count (a plant that could not be measured: ``plant K: not
  measured`` and its reason).

A plant of the frame that could not be measured does not drop the frame: the report carries it
with its ``error`` and ``n_plants_not_measured`` counts it (as ``reconstruct --measure``
reports it); the node counts ``plants_not_measured`` and warns with the reason on ``/diagnostics``.

The rig comes from the rig parameters (``--params-file RIG.yaml``, as for ``rectify_node``):
the measuring pipeline needs its world-frame ``P`` and rectification. Parameters:
``max_rate`` (Hz, 1.0; 0 = every frame), ``whole_scene`` (false: the automatic plant mask;
true: every point), ``voxel_size_mm`` (10), ``frame_id`` ("" = ``rectify_node``'s world
frame from ``stereo_geometry``, else ``canopy_world``), ``queue_size``, ``reliability``.
A frame with nothing to measure is dropped with the pipeline's one-line reason.
"""
from __future__ import annotations

import json
import time

import numpy as np
from sensor_msgs.msg import Image
from std_msgs.msg import String
from stereo_msgs.msg import DisparityImage
from visualization_msgs.msg import Marker, MarkerArray

from canopy_stereo.bag.pairing import ExactTimeSynchronizer
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.convert import COLOUR_ENCODINGS, make_header, msg_to_bgr, msg_to_disparity, stamp_to_ns
from canopy_stereo.ros.limits import check_disparity_msg, check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rig_from_node
from canopy_stereo.ros.stereo_geometry import STEREO_GEOMETRY_TOPIC, parse_stereo_geometry
from canopy_stereo.ros.tf import latched_qos

#: Version of the ``traits`` JSON layout.
TRAITS_FORMAT = 1
_STREAMS = ("left image", "disparity")


def traits_json(report: dict, stamp_ns: int, frame_id: str) -> str:
    """The ``traits`` message text of a measurement report (see the module docstring)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return json.dumps({"format": TRAITS_FORMAT, "stamp": {"sec": sec, "nanosec": nanosec},
                       "frame_id": frame_id, "report": report})


def plant_masks(measured) -> list[tuple[dict, np.ndarray]]:
    """``(plant entry of report["plants"], (H, W) bool mask)`` per measured plant: the
    plant's instance for the automatic mask, the whole measured mask otherwise."""
    plants = measured.report.get("plants") or [{"plant_index": 0, "canopy": measured.report.get("canopy", {}),
                                                "n_leaves": len(measured.report.get("leaves", []))}]
    out = []
    for plant in plants:
        index = int(plant.get("plant_index", 0))
        if measured.instances is not None and index > 0:
            out.append((plant, np.asarray(measured.instances) == index))
        else:
            out.append((plant, np.asarray(measured.mask, bool)))
    return out


def _box(points_mm, mask):
    p = np.asarray(points_mm, np.float64)[mask]
    p = p[np.all(np.isfinite(p), axis=1)]
    return (p.min(axis=0) / 1000.0, p.max(axis=0) / 1000.0) if len(p) else None


def traits_markers(measured, stamp_ns: int, frame_id: str) -> MarkerArray:
    """RViz markers of a :class:`~canopy_stereo.measure.plant.PlantMeasurement`: DELETEALL,
    then a box (metres, axis-aligned in ``frame_id``) and a label per plant."""
    header = make_header(stamp_ns, frame_id)
    markers = [Marker(header=header, action=Marker.DELETEALL)]
    for k, (plant, mask) in enumerate(plant_masks(measured)):
        box_mm = _box(measured.organized_mm, mask)
        if box_mm is None:
            continue
        lo, hi = box_mm
        c = plant.get("canopy") or {}
        box = Marker(header=header, ns="plant_box", id=k, type=Marker.CUBE, action=Marker.ADD)
        box.pose.position.x, box.pose.position.y, box.pose.position.z = (float(v) for v in (lo + hi) / 2)
        box.pose.orientation.w = 1.0
        box.scale.x, box.scale.y, box.scale.z = (float(max(v, 1e-3)) for v in hi - lo)
        box.color.r, box.color.g, box.color.b, box.color.a = 0.1, 0.8, 0.2, 0.25
        text = Marker(header=header, ns="plant_label", id=k, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD)
        text.pose.position.x, text.pose.position.y, text.pose.position.z = (float(v) for v in (lo + hi) / 2)
        text.pose.orientation.w = 1.0
        text.scale.z = 0.02
        text.color.r = text.color.g = text.color.b = text.color.a = 1.0
        if plant.get("error") is not None:
            text.text = f"plant {plant.get('plant_index', 0)}: not measured\n{plant['error']}"
        else:
            text.text = (f"plant {plant.get('plant_index', 0)}: height {c.get('height', float('nan')):.0f} mm, "
                         f"width {c.get('width', float('nan')):.0f} mm\nhull "
                         f"{c.get('hull_volume', float('nan')):.0f} cm^3, {plant.get('n_leaves', 0)} leaves")
        markers += [box, text]
    return MarkerArray(markers=markers)


class TraitsNode(CanopyNode):
    """Exact-time pairing of the rectified left image and its disparity + the measuring pipeline."""

    def __init__(self, node_name: str = "traits_node", **kwargs):
        super().__init__(node_name, **kwargs)
        declare_rig_parameters(self)
        self.declare_number("max_rate", 1.0, "measured frames per second at most (0 = every frame)",
                            minimum=0.0, maximum=100.0)
        self.declare_flag("whole_scene", False, "measure every point instead of the automatic plant mask")
        self.declare_number("voxel_size_mm", 10.0, "voxel edge of the occupancy volume (mm)",
                            minimum=0.1, maximum=1000.0)
        self.declare_text("frame_id", "", "frame of the marker positions ('' = rectify_node's world frame)")
        self.declare_number("queue_size", 15, "stamps kept while waiting for the other input",
                            minimum=1, maximum=100, read_only=True)
        self.rig = rig_from_node(self)
        self.world_frame = ""
        self._last_measured = -float("inf")
        self.sync = ExactTimeSynchronizer(2, int(self.get_parameter("queue_size").value),
                                          on_jump=self.time_jump_handler(_STREAMS))
        self.pub = self.make_publisher(String, "traits")
        self.pub_markers = self.make_publisher(MarkerArray, "traits/markers")
        self.sub_geometry = self.create_subscription(String, STEREO_GEOMETRY_TOPIC,
                                                     self.guarded(self._on_geometry), latched_qos())
        self.sub_image = self.make_subscription(Image, "left/image_raw", lambda m: self._on(0, m))
        self.sub_disp = self.make_subscription(DisparityImage, "disparity", lambda m: self._on(1, m))
        rate = float(self.get_parameter("max_rate").value)
        self.get_logger().info("measuring left/image_raw + disparity "
                               + (f"at most {rate:g} times a second" if rate > 0 else "every frame"))

    def _on_geometry(self, msg: String) -> None:
        try:
            self.world_frame = parse_stereo_geometry(msg).world_frame
        except CanopyStereoError as exc:
            self.drop(str(exc), "stereo_geometry")

    def _on(self, stream: int, msg) -> None:
        what = _STREAMS[stream]
        self.count(f"{what}_received")
        try:
            if stream == 0:
                check_image_msg(msg, expected_size=self.rig.image_size, encodings=COLOUR_ENCODINGS)
                item = msg_to_bgr(msg, expected_size=self.rig.image_size)
            else:
                check_disparity_msg(msg)
                item = msg_to_disparity(msg)
        except CanopyStereoError as exc:
            self.drop(str(exc), what)
            return
        items, dropped = self.sync.push(stream, stamp_to_ns(msg.header.stamp), item)
        for d in dropped:
            self.drop(d.reason, _STREAMS[d.stream], log=not d.reason.startswith("time jumped back"))
        if items is not None:
            self._measure(stamp_to_ns(msg.header.stamp), *items)

    def _measure(self, stamp_ns: int, bgr, frame) -> None:
        from canopy_stereo.ros.measuring import measure_graph_frame

        rate = float(self.get_parameter("max_rate").value)
        now = time.monotonic()
        if rate > 0 and now - self._last_measured < 1.0 / rate:
            self.drop(f"skipped: at most {rate:g} measurements a second (max_rate)", "frame", log=False)
            return
        self._last_measured = now
        try:
            measured = measure_graph_frame(bgr, frame, self.rig,
                                           whole_scene=bool(self.get_parameter("whole_scene").value),
                                           voxel_size_mm=float(self.get_parameter("voxel_size_mm").value))
        except CanopyStereoError as exc:
            self.drop(f"not measured: {exc}", "frame")
            return
        for plant in measured.report.get("plants", []):
            if plant.get("error") is not None:
                self.count("plants_not_measured")
                self.warn(f"plant not measured: {plant['error']}", "plant")
        frame_id = self.get_parameter("frame_id").value or self.world_frame or "canopy_world"
        self.pub.publish(String(data=traits_json(measured.report, stamp_ns, frame_id)))
        self.pub_markers.publish(traits_markers(measured, stamp_ns, frame_id))
        self.count("frames_measured")


def main(args=None) -> int:
    """``ros2 run canopy_stereo traits_node --ros-args --params-file RIG.yaml``."""
    return run_node(TraitsNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
