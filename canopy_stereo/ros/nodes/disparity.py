"""``disparity_node``: dense disparity (ELAS by default) of exact-time rectified pairs.

Subscribes ``left/image_rect`` and ``right/image_rect`` (mono8, or any 8-bit
colour encoding) and publishes ``disparity`` (``stereo_msgs/DisparityImage``):
32FC1 disparities in rectified pixels, ``f`` the rectified focal length
(pixels), ``t`` the baseline (metres), ``min_disparity``/``max_disparity`` the
search range, ``delta_d`` the matcher's resolution, ``valid_window`` the box of
valid pixels; invalid pixels are ``min_disparity - 1``. As the message
definition asks, values (and the range) are reduced by ``cx_left - cx_right``
of the rectified cameras, so depth is ``Z = f t / d``.

Parameters (changeable at run time unless marked read-only):

* ``matcher``: ``elas`` (default) or ``sgbm``;
* ``preset``: ELAS preset (``robotics``, ``middlebury``);
* ``elas.<name>``: every ELAS parameter (:class:`~canopy_stereo.elas.params.ElasParams`),
  unset = the preset's value; ``sgbm.<name>``: the SGBM matcher's parameters;
* ``disp_min``, ``disp_max``: search range in pixels, -1 = from the rig file
  (``disp_min``/``disp_max`` extras) or from the rectification;
* read-only: the rig, ``method``, ``H_left``/``H_right``, ``queue_size``, ``reliability``.

New values are validated before they are accepted (an invalid ELAS combination
is refused with the reason); they apply from the next frame.
"""
from __future__ import annotations

import inspect
import threading

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from sensor_msgs.msg import Image
from stereo_msgs.msg import DisparityImage

from canopy_stereo.disparity import available_matchers, compute_disparity, get_matcher
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.pipeline.reconstruct import disparity_range_for
from canopy_stereo.ros.convert import COLOUR_ENCODINGS, disparity_to_msg, msg_to_mono, stamp_to_ns
from canopy_stereo.ros.limits import check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.params import declare_rig_parameters, rectification_from_node, rig_from_node
from canopy_stereo.ros.sync import ExactTimeSynchronizer

_RANGE = ("disp_min", "disp_max")


def default_matcher() -> str:
    """``elas`` when :mod:`canopy_stereo.elas` is importable, else ``sgbm``."""
    return "elas" if "elas" in available_matchers() else "sgbm"


def matcher_parameters(matcher: str) -> dict:
    """``name -> default`` of the tunable parameters of a registered matcher
    (ELAS: the fields of ``ElasParams`` with the ``robotics`` preset's values)."""
    if matcher == "elas":
        from dataclasses import fields

        from canopy_stereo.elas.params import PRESETS

        base = PRESETS["robotics"]
        return {f.name: getattr(base, f.name) for f in fields(base) if f.name not in _RANGE}
    sig = inspect.signature(get_matcher(matcher))
    return {n: p.default for n, p in sig.parameters.items()
            if p.kind == p.KEYWORD_ONLY and n not in _RANGE and p.default is not inspect.Parameter.empty}


def _coerce(value, like):
    """Give a ROS parameter value the Python type of the matcher's default."""
    if like is None or value is None:
        return value
    if isinstance(like, bool):
        if not isinstance(value, bool):
            raise CanopyStereoError(f"expected true/false, got {value!r}")
        return value
    if isinstance(like, int):
        if isinstance(value, bool) or float(value) != int(value):
            raise CanopyStereoError(f"expected an integer, got {value!r}")
        return int(value)
    if isinstance(like, float):
        if isinstance(value, bool):
            raise CanopyStereoError(f"expected a number, got {value!r}")
        return float(value)
    return type(like)(value)


class DisparityNode(CanopyNode):
    """Exact-time pairing + matcher (see module docstring)."""

    def __init__(self, node_name: str = "disparity_node", **kwargs):
        super().__init__(node_name, **kwargs)
        declare_rig_parameters(self)
        self.declare_parameter("queue_size", 5, ParameterDescriptor(read_only=True))
        self.declare_parameter("matcher", default_matcher(), ParameterDescriptor(
            description="disparity matcher: elas or sgbm"))
        self.declare_parameter("preset", "robotics", ParameterDescriptor(
            description="ELAS preset: robotics or middlebury"))
        self.declare_parameter("disp_min", -1, ParameterDescriptor(
            description="smallest disparity searched (pixels); -1: from the rig/rectification"))
        self.declare_parameter("disp_max", -1, ParameterDescriptor(
            description="largest disparity searched (pixels); -1: from the rig/rectification"))
        self._defaults = {}
        for matcher in ("elas", "sgbm"):
            try:
                defaults = matcher_parameters(matcher)
            except CanopyStereoError:
                continue
            for name, default in defaults.items():
                self._defaults[f"{matcher}.{name}"] = default
                self.declare_parameter(f"{matcher}.{name}", None, ParameterDescriptor(
                    dynamic_typing=True,
                    description=f"{matcher} parameter {name} (unset: preset/default {default!r})"))
        self.rig = rig_from_node(self)
        self.rect = rectification_from_node(self, self.rig)
        if self.rect.method == "fusiello":
            self.f = float(self.rect.focal_length)
            self.t = float(self.rect.baseline) * self.rig.metres_per_unit
        else:
            self.f = self.t = 0.0
            self.get_logger().info("hartley rectification: f and t are 0 (no metric rectified camera)")
        self._config_lock = threading.Lock()
        self.config = self._build_config({})
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.sync = ExactTimeSynchronizer(2, int(self.get_parameter("queue_size").value))
        self.pub = self.make_publisher(DisparityImage, "disparity")
        self.sub_left = self.make_subscription(Image, "left/image_rect", lambda m: self._on_image(0, m))
        self.sub_right = self.make_subscription(Image, "right/image_rect", lambda m: self._on_image(1, m))
        c = self.config
        self.get_logger().info(f"matcher {c['matcher']}, disparities [{c['disp_min']}, {c['disp_max']}], "
                               f"f {self.f:.2f} px, t {self.t:.5f} m")

    # ------------------------------------------------------------------ parameters
    def _build_config(self, changes: dict) -> dict:
        """Matcher configuration from the current parameters with ``changes`` applied."""
        def value(name):
            return changes[name] if name in changes else self.get_parameter(name).value

        matcher = value("matcher")
        get_matcher(matcher)  # raises for unknown/unavailable matchers
        dmin, dmax = int(value("disp_min")), int(value("disp_max"))
        for name, v in (("disp_min", dmin), ("disp_max", dmax)):
            if v < -1:
                raise CanopyStereoError(f"{name} must be >= 0 pixels, or -1 for the rig's range; got {v}")
        dmin, dmax = disparity_range_for(self.rig, self.rect, None if dmin < 0 else dmin,
                                         None if dmax < 0 else dmax)
        params = {}
        for key, default in self._defaults.items():
            prefix, name = key.split(".", 1)
            v = value(key)
            if prefix == matcher and v is not None:
                try:
                    params[name] = _coerce(v, default)
                except (CanopyStereoError, TypeError, ValueError) as exc:
                    raise CanopyStereoError(f"{key}: {exc}") from None
        if matcher == "elas":
            from canopy_stereo.elas.params import make_params

            params["preset"] = value("preset")
            make_params(params["preset"], disp_min=dmin, disp_max=dmax,
                        **{k: v for k, v in params.items() if k != "preset"})
            subpixel = params.get("subpixel", False)
            delta_d = 1.0 / 16.0 if subpixel else 1.0
        else:
            delta_d = 1.0 / 16.0
        return {"matcher": matcher, "disp_min": dmin, "disp_max": dmax, "params": params,
                "delta_d": delta_d}

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters}
        try:
            config = self._build_config(changes)
        except CanopyStereoError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        with self._config_lock:
            self.config = config
        return SetParametersResult(successful=True)

    # ------------------------------------------------------------------ frames
    def _on_image(self, side: int, msg: Image) -> None:
        name = ("left", "right")[side]
        self.count(f"{name}_received")
        try:
            check_image_msg(msg, expected_size=self.rect.size, encodings=COLOUR_ENCODINGS)
            img = msg_to_mono(msg)
        except CanopyStereoError as exc:
            self.drop(str(exc), f"{name} rectified image")
            return
        items, dropped = self.sync.push(side, stamp_to_ns(msg.header.stamp), (img, msg.header.frame_id))
        for d in dropped:
            self.drop(d.reason, f"{('left', 'right')[d.stream]} rectified image")
        if items is not None:
            (left, frame_id), (right, _) = items
            self._match(stamp_to_ns(msg.header.stamp), frame_id, left, right)

    def _match(self, stamp_ns: int, frame_id: str, left, right) -> None:
        with self._config_lock:
            c = self.config
        if left.shape != right.shape:
            self.drop(f"rectified pair sizes differ: {left.shape[::-1]} vs {right.shape[::-1]}", "pair")
            return
        disp = compute_disparity(left, right, matcher=c["matcher"], disp_min=c["disp_min"],
                                 disp_max=c["disp_max"], **c["params"])
        self.pub.publish(disparity_to_msg(disp, self.f, self.t, c["disp_min"], c["disp_max"],
                                          c["delta_d"], stamp_ns, frame_id, self.rect.doffs))
        self.count("disparities_published")


def main(args=None) -> int:
    """``ros2 run canopy_stereo disparity_node --ros-args --params-file RIG.yaml``."""
    return run_node(DisparityNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
