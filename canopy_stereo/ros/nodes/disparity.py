"""``disparity_node``: dense disparity (ELAS by default) of exact-time rectified pairs.

Subscribes ``left/image_rect`` and ``right/image_rect`` (mono8, or any 8-bit
colour encoding) with their rectified cameras ``left/image_rect/camera_info`` and
``right/image_rect/camera_info`` (four-way exact-time pairing, as stereo_image_proc's
disparity node), and publishes ``disparity`` (``stereo_msgs/DisparityImage``):
32FC1 disparities in rectified pixels, ``f`` the rectified focal length
(pixels) and ``t`` the baseline (metres), both read from the two ``CameraInfo``
``P`` matrices (``f = P_r[0,0]``, ``t = -P_r[0,3] / f``), ``min_disparity``/``max_disparity``
the search range, ``delta_d`` the matcher's resolution (from the registry), ``valid_window`` the box of
valid pixels; invalid pixels are ``min_disparity - 1``. As the message definition
asks, values (and the range) are reduced by ``cx_left - cx_right`` of the two
``P`` (0 for the package's Fusiello rectification), so depth is ``Z = f t / d``.
An uncalibrated (Hartley) camera pair gives ``f = t = 0``. This node holds no rig.
It also publishes ``disparity/matching`` and ``disparity/matched`` (``std_msgs/Header``, a few
bytes): the stamp and frame of each pair as the matcher takes it and as it is done with it, by
which ``rectify_node`` (``follow_matcher``) rectifies only the pairs the matcher can take, just in
time.

Parameters (changeable at run time unless marked read-only):

* ``matcher``: a registered matcher (:mod:`canopy_stereo.disparity.registry`): ``elas``
  (default) or ``sgbm``;
* ``preset``: ELAS preset (``robotics``, ``middlebury``);
* ``<matcher>.<name>``: every parameter of every available matcher, declared from the
  registry's schema (description, type, range): ``elas.<name>`` every ELAS parameter
  (:class:`~canopy_stereo.elas.params.ElasParams`), unset = the preset's value;
  ``sgbm.<name>`` the SGBM matcher's;
* ``disp_min``, ``disp_max``: search range in pixels (a rig file's ``disp_min``/``disp_max``
  set them); -1 = from the cameras: the working distance ``near_m``..``far_m``, else 0 to
  the disparity of a point 8 baselines away (``f / 8``), or 0 to 128 for an uncalibrated pair;
* ``near_m``, ``far_m``: working distance in metres along the optical axis (a rig file's
  ``near_m``/``far_m`` set them; 0 = 8 baselines / infinity), the range when ``disp_min``/
  ``disp_max`` are -1 (as ``reconstruct``'s, :func:`~canopy_stereo.pipeline.reconstruct.disparity_range_for`);
* ``threads``: thread budget of the ELAS kernels (numba), the node's share of the cores
  when other nodes run beside it: -1 (default) = automatic, one thread for frames up to
  0.5 Mpixel (640x480-class: the graph's other nodes keep the second core busy) and every
  core above (1280x720) (:func:`~canopy_stereo.elas.parallel.budget_threads`); 0 = every
  core; N = N threads;
* ``roi`` (read-only, default false; the launch file and ``canopy_graph`` set it when the cloud
  is masked): subscribe ``left/mask`` (segment_node's) and match only in the plant region of
  the previous frames' masks (:class:`~canopy_stereo.disparity.roi.RoiPlanner`), dilated by
  ``roi_margin`` pixels, with the columns the search needs; the full frame on the first frame,
  when the masks stop, on a cut (an empty mask, the plant area jumping, the plant reaching the
  border of the window its frame was matched in: a new plant or fast motion), every
  ``roi_full_every`` frames, and when the window would cover more than ``roi_max_share`` of
  the frame. The ``DisparityImage`` stays full size, invalid outside the window (its
  ``valid_window`` says where); ``/diagnostics`` reports the ``matched share`` of the frame
  and the reason of each full frame;
* ``parallel_pairs`` (read-only, default 1): pairs matched at once, each on thread(s) of its own
  (``threads`` each). The maps do not change (no frame is split); the disparities are published
  in stamp order. It raises the rate when the matcher is the slowest stage and the machine has
  cores left, at a longer latency (each pair waits for the one before it, and shares the cores):
  on 2 cores with the whole graph at 30 pairs/s, 640x480, 2 pairs gave 25.1 instead of 21.0
  clouds/s on the Aloe scene (disparities to 130 px) but a median latency of 146 instead of
  102 ms, and no gain on the Plants frames (``benchmarks/bench_graph.py``);
* read-only: ``queue_size``, ``waiting_pairs``, ``reliability``, ``diagnostic_period``.

This is the slowest stage: the matcher runs in worker threads (``parallel_pairs``) on the complete pairs
(:class:`~canopy_stereo.ros.nodes.base.LatestOnly`), at most ``waiting_pairs`` (1)
waiting; when the cameras are faster than the matcher, the oldest waiting pairs are
dropped as superseded, so latency stays bounded. Stamps that go back reset the pairing.

New values are validated before they are accepted (an invalid ELAS combination
is refused with the reason); they apply from the next frame.
"""
from __future__ import annotations

import threading

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from stereo_msgs.msg import DisparityImage

from canopy_stereo.bag.pairing import ExactTimeSynchronizer
from canopy_stereo.disparity import (  # noqa: F401
    available_matchers,
    compute_disparity,
    default_matcher,
    matcher_names,
    matcher_spec,
    preset_names,
)
from canopy_stereo.disparity.roi import (
    DEFAULT_FULL_EVERY,
    DEFAULT_MARGIN,
    DEFAULT_MAX_SHARE,
    RoiPlanner,
    disparity_in_window,
)
from canopy_stereo.elas.parallel import AUTO_THREADS, budget_threads
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.ros.cdr_views import image_view
from canopy_stereo.ros.convert import (
    COLOUR_ENCODINGS,
    camera_info_matrices,
    disparity_to_msg,
    is_calibrated,
    make_header,
    msg_to_image,
    msg_to_mono,
    stamp_to_ns,
)
from canopy_stereo.ros.limits import check_image_msg
from canopy_stereo.ros.nodes.base import CanopyNode, run_node
from canopy_stereo.ros.nodes.rectify import MATCHED_TOPIC, MATCHING_TOPIC, RECT_INFO_TOPICS
from canopy_stereo.ros.params import number_descriptor

_RANGE = ("disp_min", "disp_max")

#: Disparities searched while validating a matcher configuration whose range comes from the cameras.
TYPICAL_RANGE = 64


def matcher_parameters(matcher: str) -> dict:
    """``name -> default`` of the tunable parameters of a registered matcher
    (:meth:`~canopy_stereo.disparity.registry.MatcherSpec.defaults`; ELAS: its default
    preset's values)."""
    return matcher_spec(matcher).defaults()


def matcher_parameter_descriptor(spec, parameter) -> ParameterDescriptor:
    """Descriptor of ``<matcher>.<name>`` from the registry's schema: its description and
    what unset means; numbers with their range (dynamic typing: unset is allowed)."""
    description = parameter.description
    if parameter.default is not None:
        default = spec.defaults()[parameter.name]
        description += (f" (unset: the preset's; {spec.default_preset}: {default!r})" if spec.presets
                        else f" (unset: {default!r})")
    if parameter.choices:
        description += f" ({' | '.join(parameter.choices)})"
    if parameter.numeric and parameter.minimum is not None and parameter.maximum is not None:
        return number_descriptor(description, minimum=parameter.minimum, maximum=parameter.maximum,
                                 integer=parameter.kind is int, dynamic=True)
    return ParameterDescriptor(description=description, dynamic_typing=True)


def _default_preset() -> str:
    """The default preset of the first available matcher that has presets ("" if none)."""
    for name in [default_matcher()] + available_matchers():
        try:
            spec = matcher_spec(name)
        except CanopyStereoError:
            continue
        if spec.presets:
            return spec.default_preset
    return ""


class DisparityNode(CanopyNode):
    """Exact-time pairing + matcher (see module docstring)."""

    def __init__(self, node_name: str = "disparity_node", **kwargs):
        super().__init__(node_name, **kwargs)
        self.declare_number("queue_size", 5, "rectified images and camera_infos kept per stream while "
                            "waiting for the others with the same stamp",
                            minimum=1, maximum=100, read_only=True)
        self.declare_number("waiting_pairs", 1, "complete pairs kept waiting while the matcher is busy; "
                            "when more arrive the oldest is dropped (the newest win, latency stays bounded)",
                            minimum=1, maximum=100, read_only=True)
        self.declare_number("parallel_pairs", 1, "rectified pairs matched at once, each on threads of its own "
                            "(frame-level parallelism: the same maps, published in stamp order); more pairs per "
                            "second when the matcher is the slowest stage and cores are left, at a longer latency",
                            minimum=1, maximum=8, read_only=True)
        self.declare_text("matcher", default_matcher(), "disparity matcher", choices=tuple(matcher_names()))
        self.declare_number("threads", AUTO_THREADS, "thread budget of the ELAS kernels: -1 = automatic (1 thread "
                            "up to 0.5 Mpixel frames, e.g. 640x480; every core above, e.g. 1280x720), "
                            "0 = every core, N = N threads", minimum=-1, maximum=1024)
        self.declare_text("preset", _default_preset(), "preset of the matchers that have presets (ELAS: "
                          "defaults of the elas.* parameters)", choices=tuple(preset_names()))
        self.declare_number("disp_min", -1, "smallest disparity searched (pixels); "
                            "-1 = from the rectified cameras", minimum=-1, maximum=4096)
        self.declare_number("disp_max", -1, "largest disparity searched (pixels); "
                            "-1 = from the rectified cameras", minimum=-1, maximum=4096)
        for name, text in (("near_m", "working distance: nearest depth searched (metres along the optical "
                                      "axis; 0 = 8 baselines); disp_max wins when set"),
                           ("far_m", "working distance: farthest depth searched (metres; 0 = infinity); "
                                     "disp_min wins when set")):
            # dynamic: a rig file's 'near_m: 1' (an integer) is as good as 1.0
            self.declare_parameter(name, 0.0, number_descriptor(text, minimum=0.0, maximum=1e6, integer=False,
                                                                dynamic=True))
        for matcher in available_matchers():
            spec = matcher_spec(matcher)
            for parameter in spec.parameters:
                self.declare_parameter(f"{matcher}.{parameter.name}", None,
                                       matcher_parameter_descriptor(spec, parameter))
        self.declare_flag("roi", False, "match only in the plant region of the previous masks (left/mask), "
                          "dilated by roi_margin; the full frame on a cut, a new plant and every roi_full_every "
                          "frames", read_only=True)
        self.declare_number("roi_margin", DEFAULT_MARGIN, "pixels added around the plant of the previous masks "
                            "(its motion between frames and the matcher's neighbourhood)", minimum=0, maximum=4096)
        self.declare_number("roi_full_every", DEFAULT_FULL_EVERY, "with roi: a full frame at least every this "
                            "many frames (plants appearing anywhere are found); 1 = always the full frame",
                            minimum=1, maximum=100000)
        self.declare_number("roi_max_share", DEFAULT_MAX_SHARE, "with roi: a window covering more than this "
                            "share of the frame is matched as the full frame", minimum=0.01, maximum=1.0)
        self.declare_frame_size()
        self.image_width_seen = 0  # width of the latest rectified camera_info (0: none yet)
        self._config_lock = threading.Lock()
        self.config = self._build_config({})
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # streams: 0 left image, 1 right image, 2 left camera_info, 3 right camera_info
        self.sync = ExactTimeSynchronizer(4, int(self.get_parameter("queue_size").value),
                                          on_jump=self.time_jump_handler(_STREAMS))
        self.pub = self.make_publisher(DisparityImage, "disparity")
        #: the stamp of each pair as the matcher takes it (rectify_node's follow_matcher paces itself by it)
        self.pub_matching = self.make_publisher(Header, MATCHING_TOPIC)
        self.pub_matched = self.make_publisher(Header, MATCHED_TOPIC)
        w, h = self.warm_up_size()
        self.matching = self.latest_only(self._match, "rectified pair",
                                         depth=int(self.get_parameter("waiting_pairs").value),
                                         workers=int(self.get_parameter("parallel_pairs").value))
        self.warm_up(f"{self.config['matcher']} on {w}x{h} pairs", lambda: self.matching.call(self._warm_up))
        self.sub_left = self.make_subscription(Image, "left/image_rect", lambda m: self._on_image(0, m))
        self.sub_right = self.make_subscription(Image, "right/image_rect", lambda m: self._on_image(1, m))
        self.sub_info_left = self.make_subscription(CameraInfo, RECT_INFO_TOPICS[0],
                                                    lambda m: self._on_info(2, m))
        self.sub_info_right = self.make_subscription(CameraInfo, RECT_INFO_TOPICS[1],
                                                     lambda m: self._on_info(3, m))
        self.roi = bool(self.get_parameter("roi").value)
        self._roi_lock = threading.Lock()
        self.roi_planner = self._make_planner({})
        if self.roi:
            # read in place from the serialized message (cdr_views: no deserialisation)
            self.sub_mask = self.make_subscription(Image, "left/mask", self._on_mask, parse=image_view)
        self.camera = None  # (f, t, doffs) of the latest camera_info pair, for the log
        self.expected_size = None  # (width, height) of the latest rectified camera_info
        c = self.config
        rng = ("from the cameras" if c["disp_min"] is None or c["disp_max"] is None
               else f"[{c['disp_min']}, {c['disp_max']}]")
        self.get_logger().info(f"matcher {c['matcher']}, disparities {rng}")

    # ------------------------------------------------------------------ parameters
    def _build_config(self, changes: dict) -> dict:
        """Matcher configuration from the current parameters with ``changes`` applied."""
        def value(name):
            return changes[name] if name in changes else self.get_parameter(name).value

        matcher = value("matcher")
        spec = matcher_spec(matcher)  # raises for unknown/unavailable matchers
        dmin, dmax = int(value("disp_min")), int(value("disp_max"))
        dmin, dmax = (None if dmin < 0 else dmin), (None if dmax < 0 else dmax)
        if dmin is not None and dmax is not None and dmax <= dmin:
            raise CanopyStereoError(f"disp_max ({dmax}) must be greater than disp_min ({dmin})")
        width = self.image_width_seen or int(self.get_parameter("image_width").value)
        if dmax is not None and width > 0 and dmax >= width:  # the image size is known: check against it
            raise CanopyStereoError(f"disp_max ({dmax}) must be smaller than the image width ({width} px)")
        params = {}
        for name in available_matchers():  # every value set is checked; the active matcher's are used
            for parameter in matcher_spec(name).parameters:
                key = f"{name}.{parameter.name}"
                v = value(key)
                if v is not None:
                    v = parameter.coerce(v, label=key)
                    if name == matcher:
                        params[parameter.name] = v
        if spec.presets:
            params["preset"] = value("preset")
        # validate with the given range, or a typical one where it comes from the cameras
        lo = 0 if dmin is None else dmin
        params = spec.check(params, lo, disp_max=dmax if dmax is not None else lo + TYPICAL_RANGE)
        near, far = float(value("near_m")) or None, float(value("far_m")) or None
        if near is not None and far is not None and far <= near:
            raise CanopyStereoError(f"far_m ({far:g} m) must be greater than near_m ({near:g} m)")
        return {"matcher": matcher, "disp_min": dmin, "disp_max": dmax, "near_m": near, "far_m": far,
                "params": params,
                "delta_d": spec.resolution_for(params), "threads": int(value("threads"))}

    def _on_set_parameters(self, parameters) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters}
        try:
            config = self._build_config(changes)
        except CanopyStereoError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if any(name.startswith("roi_") for name in changes):
            try:
                planner = self._make_planner(changes)
            except CanopyStereoError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            with self._roi_lock:
                self.roi_planner = planner
        with self._config_lock:
            self.config = config
        return SetParametersResult(successful=True)

    def _make_planner(self, changes: dict) -> RoiPlanner:
        """A fresh :class:`RoiPlanner` of the ``roi_*`` parameters with ``changes`` applied."""
        def value(name):
            return changes[name] if name in changes else self.get_parameter(name).value

        return RoiPlanner(margin=int(value("roi_margin")), full_every=int(value("roi_full_every")),
                          max_share=float(value("roi_max_share")))

    def _on_mask(self, msg: Image) -> None:
        """A plant mask of segment_node: the window of the next pairs follows it."""
        self.count("masks_received")
        try:
            check_image_msg(msg, expected_size=self.expected_size, encodings=("mono8", "8UC1"))
            mask = msg_to_image(msg, ("mono8", "8UC1"))
        except CanopyStereoError as exc:
            self.drop(str(exc), "mask")
            return
        with self._roi_lock:
            self.roi_planner.observe(stamp_to_ns(msg.header.stamp), mask)

    # ------------------------------------------------------------------ frames
    def _on_image(self, side: int, msg: Image) -> None:
        name = ("left", "right")[side]
        self.count(f"{name}_received")
        try:
            check_image_msg(msg, expected_size=self.expected_size, encodings=COLOUR_ENCODINGS)
            img = msg_to_mono(msg)
        except CanopyStereoError as exc:
            self.drop(str(exc), f"{name} rectified image")
            return
        self._push(side, msg, (img, msg.header.frame_id))

    def _on_info(self, stream: int, msg: CameraInfo) -> None:
        self.count(f"{('left', 'right')[stream - 2]}_camera_info_received")
        if msg.width > 0 and msg.height > 0:  # images must have the rectified cameras' size
            self.expected_size = (int(msg.width), int(msg.height))
            self.image_width_seen = int(msg.width)
        self._push(stream, msg, msg)

    def _push(self, stream: int, msg, item) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        items, dropped = self.sync.push(stream, stamp, item)
        self.drop_unpaired(dropped, _STREAMS)
        if items is not None:
            (left, frame_id), (right, _), info_l, info_r = items
            self.matching.submit(stamp, frame_id, left, right, info_l, info_r)

    def _warm_up(self) -> None:
        """The configured matcher on a synthetic textured pair of the rig's size (its kernels
        loaded or compiled, its buffers allocated), nothing published."""
        from canopy_stereo.sim.stereo_pair import synthetic_pair

        c = self.config
        w, h = self.warm_up_size()
        lo = 0 if c["disp_min"] is None else c["disp_min"]
        hi = lo + TYPICAL_RANGE if c["disp_max"] is None else c["disp_max"]
        left, right, _ = synthetic_pair(w, h, plane=(0.0, 0.0, float((lo + hi) // 2)), texture="blocks")
        apply_thread_budget(c["threads"], pixels=w * h)
        disp = compute_disparity(left, right, matcher=c["matcher"], disp_min=lo, disp_max=hi, **c["params"])
        disparity_to_msg(disp, 500.0, 0.1, lo, hi, delta_d=c["delta_d"], stamp_ns=1, frame_id="")

    def _match(self, stamp_ns: int, frame_id: str, left, right, info_l, info_r) -> None:
        """One pair, between its ``disparity/matching`` and ``disparity/matched`` headers."""
        self.pub_matching.publish(make_header(stamp_ns, frame_id))
        try:
            self._match_pair(stamp_ns, frame_id, left, right, info_l, info_r)
        finally:
            self.pub_matched.publish(make_header(stamp_ns, frame_id))

    def _match_pair(self, stamp_ns: int, frame_id: str, left, right, info_l, info_r) -> None:
        with self._config_lock:
            c = self.config
        if left.shape != right.shape:
            self.drop(f"rectified pair sizes differ: {left.shape[::-1]} vs {right.shape[::-1]}", "pair")
            return
        try:
            f, t, doffs = stereo_parameters(info_l, info_r)
        except CanopyStereoError as exc:
            self.drop(str(exc), "camera_info pair")
            return
        if self.camera != (f, t, doffs):
            self.camera = (f, t, doffs)
            self.get_logger().info(f"rectified cameras: f {f:.2f} px, t {t:.5f} m, "
                                   f"cx_left - cx_right {doffs:.2f} px")
        dmin, dmax = resolve_disparity_range(c["disp_min"], c["disp_max"], f, t=t, doffs=doffs,
                                             near_m=c["near_m"], far_m=c["far_m"])
        window = None
        if self.roi:
            with self._roi_lock:
                window, reason = self.roi_planner.plan(stamp_ns, image_size=left.shape[1::-1], disp_min=dmin,
                                                       disp_max=dmax)
            self.diagnostics.sample("matched share", 1.0 if window is None else window.matched_share)
            if window is None:
                self.diagnostics.note(f"full frame: {reason}")
        if window is None:
            apply_thread_budget(c["threads"], pixels=left.shape[0] * left.shape[1])
            disp = compute_disparity(left, right, matcher=c["matcher"], disp_min=dmin,
                                     disp_max=dmax, **c["params"])
        else:  # the automatic budget follows the pixels matched
            apply_thread_budget(c["threads"], pixels=(window.xb - window.xa) * (window.yb - window.ya))
            disp = disparity_in_window(left, right, window, matcher=c["matcher"], disp_min=dmin,
                                       disp_max=dmax, **c["params"])
        msg = disparity_to_msg(disp, f, t, dmin, dmax, delta_d=c["delta_d"], stamp_ns=stamp_ns,
                               frame_id=frame_id, doffs=doffs)
        with self.matching.in_turn():  # several pairs at once: published in the order they came
            self.count("disparities_published")
            self.pub.publish(msg)


_STREAMS = ("left rectified image", "right rectified image", "left camera_info", "right camera_info")


def apply_thread_budget(threads: int, *, pixels: int = 0) -> int:
    """Let the ELAS kernels called from this thread use the ``threads`` budget for a frame of
    ``pixels`` (numba's setting is per thread; -1 = automatic by frame size, 0 = every core,
    N = N threads, capped at ``NUMBA_NUM_THREADS``: :func:`~canopy_stereo.elas.parallel.budget_threads`);
    returns the count in force."""
    import numba

    limit = int(numba.config.NUMBA_NUM_THREADS)
    n = budget_threads(threads, pixels=pixels, limit=limit)
    if numba.get_num_threads() != n:
        numba.set_num_threads(n)
    return n


def stereo_parameters(info_left, info_right) -> tuple[float, float, float]:
    """``(f, t, doffs)`` of a rectified ``CameraInfo`` pair: focal length (pixels), baseline
    (metres), ``cx_left - cx_right`` (pixels); ``(0, 0, 0)`` for an uncalibrated pair."""
    if not (is_calibrated(info_left) and is_calibrated(info_right)):
        return 0.0, 0.0, 0.0
    Pl, Pr = camera_info_matrices(info_left)[3], camera_info_matrices(info_right)[3]
    f = float(Pr[0, 0])
    t = -float(Pr[0, 3]) / f
    if not t > 0:
        raise CanopyStereoError(f"right camera_info has no baseline (P[0, 3] = {Pr[0, 3]:g}, "
                                "must be -f * baseline < 0)")
    if abs(Pl[0, 0] - f) > 1e-6 * f or abs(Pl[1, 2] - Pr[1, 2]) > 1e-3:
        raise CanopyStereoError("the camera_info pair is not rectified (focal lengths or principal "
                                "rows differ)")
    return f, t, float(Pl[0, 2] - Pr[0, 2])


def resolve_disparity_range(disp_min, disp_max, f: float, *, t: float = 0.0, doffs: float = 0.0,
                            near_m: float | None = None, far_m: float | None = None) -> tuple[int, int]:
    """Search range (rectified pixels): the given values, else from the cameras
    (:func:`~canopy_stereo.geometry.rectification.metric_disparity_range`: the working
    distance ``near_m``..``far_m`` metres, default infinity to 8 baselines away, ``f / 8``
    for ``doffs = 0``); 0 to 128 for an uncalibrated pair."""
    from canopy_stereo.geometry.rectification import metric_disparity_range

    lo, hi = (metric_disparity_range(f, t, doffs=doffs, near_depth=near_m, far_depth=far_m)
              if f > 0 and t > 0 else (0, 128))
    lo = lo if disp_min is None else int(disp_min)
    hi = hi if disp_max is None else int(disp_max)
    if hi <= lo:
        raise CanopyStereoError(f"disp_max ({hi}) must be greater than disp_min ({lo})")
    return lo, hi


def main(args=None) -> int:
    """``ros2 run canopy_stereo disparity_node --ros-args --params-file RIG.yaml``."""
    return run_node(DisparityNode, args)


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
