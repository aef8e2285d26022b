"""The whole node graph in one process.

:class:`CanopyGraph` creates ``rectify_node``, ``disparity_node``,
``segment_node`` and ``point_cloud_node`` (plus two ``camera_node`` for live
capture) with the rig's parameters in one process. By default every node gets
its own single-threaded executor and thread (``executor="per-node"``): a
node's callbacks run one at a time, as in a process of its own, while
different stages of consecutive frames run concurrently (OpenCV and the numba
kernels release the GIL), and a thread whose node has nothing to do sleeps in
``rcl_wait``. ``executor="multi"`` puts all nodes on one rclpy
``MultiThreadedExecutor`` instead; on the 2-core development machine that is
slower (about 10 against 13-19 frames/s, twice the latency) because its
dispatcher rebuilds and re-polls the wait set in Python while holding the GIL.

Between the graph's own nodes messages travel over an
:class:`~canopy_stereo.ros.intra_process.IntraProcessBus` (``intra_process``, default on):
the message object is handed over instead of being serialized through DDS, which held
the GIL for about 40 % of its time; everything is still published on DDS for recorders,
RViz and other processes.

The ``canopy_graph`` executable around it is :mod:`canopy_stereo.ros.canopy_graph`;
:mod:`canopy_stereo.ros.runner` replays a bag through it.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.rig import Rig
from canopy_stereo.ros.camera_info import default_camera_frame
from canopy_stereo.ros.intra_process import IntraProcessBus
from canopy_stereo.ros.params import parameters_from_dict, rig_parameter_overrides

#: Default thread count of the ``multi`` executor: enough for every stage to have a frame in flight.
DEFAULT_THREADS = 6

#: Executor layouts of :class:`CanopyGraph`.
EXECUTOR_CHOICES = ("per-node", "multi")


@dataclass
class GraphOptions:
    """What to build and how.

    Attributes:
        namespace: namespace of every node (topics ``<namespace>/left/image_raw``, ...).
        matcher: disparity matcher (None: the node's default, ELAS when available).
        segment: run ``segment_node``.
        use_mask: ``point_cloud_node`` keeps only masked pixels (implies ``segment``), and
            ``disparity_node`` matches only in the plant region of the previous masks (its ``roi``).
        segment_depth_cue: ``segment_node`` seeds GrabCut with the disparity too (its
            ``depth_cue`` parameter: near = plant, as ``canopy-stereo segment`` does).
        organized: organized clouds (NaN for invalid) instead of dense ones.
        reliability: publisher reliability of every node.
        node_parameters: node name -> extra parameters (e.g. ``{"disparity_node":
            {"elas.subsampling": True}}``).
        parameter_services: start the parameter services (``ros2 param``) of each node.
        executor: ``"per-node"`` (one single-threaded executor and thread per node)
            or ``"multi"`` (one rclpy ``MultiThreadedExecutor`` for all nodes).
        threads: threads of the ``multi`` executor.
        recut_every: segment_node's full-GrabCut period (frames; None: the node's default, 10;
            1 = every frame; :mod:`canopy_stereo.segmentation.propagate`).
        propagate_scale: segment_node's scale of the frames between full cuts (None: its ``scale``).
        disparity_threads: disparity_node's thread budget (None: the node's default).
        intra_process: messages between the graph's nodes travel over an
            :class:`~canopy_stereo.ros.intra_process.IntraProcessBus` (the message object,
            no DDS; outputs still go to DDS for everyone else); False: through DDS only.
        traits: run ``traits_node`` too (live traits on ``traits`` and ``traits/markers``).
        parent_frame, mount, camera_mount, publish_tf, frame_prefix: ``rectify_node``'s
            mounting parameters (:mod:`canopy_stereo.ros.mounting`; ``mount``/``camera_mount``
            seven numbers or None); the cameras' frame ids get ``frame_prefix`` too.
    """

    namespace: str = "/stereo"
    matcher: str | None = None
    segment: bool = True
    use_mask: bool = False
    segment_depth_cue: bool = False
    organized: bool = False
    reliability: str = "reliable"
    node_parameters: dict = field(default_factory=dict)
    parameter_services: bool = True
    threads: int = DEFAULT_THREADS
    executor: str = "per-node"
    recut_every: int | None = None
    propagate_scale: float | None = None
    disparity_threads: int | None = None
    intra_process: bool = True
    traits: bool = False
    parent_frame: str = ""
    mount: list | None = None
    camera_mount: list | None = None
    publish_tf: bool = True
    frame_prefix: str = ""

    def mounting_parameters(self) -> dict:
        """``rectify_node``'s mounting parameters of these options (unset ones left out)."""
        out = {"parent_frame": self.parent_frame, "publish_tf": bool(self.publish_tf),
               "frame_prefix": self.frame_prefix}
        for name in ("mount", "camera_mount"):
            if getattr(self, name) is not None:
                out[name] = [float(v) for v in getattr(self, name)]
        return out

    def output_topics(self) -> dict:
        """The graph's outputs a recording holds (``canopy_graph --record``, ``run --record``):
        topic relative to :attr:`namespace` -> message class. The mask with ``segment`` or
        ``use_mask``, the live traits (``traits`` JSON and ``traits/markers``) with ``traits``."""
        from sensor_msgs.msg import CameraInfo, Image, PointCloud2
        from stereo_msgs.msg import DisparityImage

        out = {"points2": PointCloud2, "disparity": DisparityImage, "left/depth": Image,
               "left/depth/camera_info": CameraInfo, "left/image_rect/camera_info": CameraInfo,
               "right/image_rect/camera_info": CameraInfo}
        if self.segment or self.use_mask:
            out["left/mask"] = Image
        if self.traits:
            from std_msgs.msg import String
            from visualization_msgs.msg import MarkerArray

            out.update({"traits": String, "traits/markers": MarkerArray})
        return out


class CanopyGraph:
    """The processing nodes (and optional cameras) of one rig, spun in one process.

    Args:
        rig: the rig (its extras, e.g. ``disp_min``, become node parameters too).
        context: an initialised rclpy context (:func:`canopy_stereo.ros.context.ros_context`).
        options: :class:`GraphOptions`.
        cameras: ``(left_params, right_params)`` for two ``camera_node`` (``device``,
            ``fps``, ...), or ``(params,)`` for one ``camera_node`` of a one-device stereo
            camera (with its ``layout``), or None when frames come from elsewhere (a bag). With cameras,
            ``rectify_node`` gets their ``fps`` and pairs within half a frame period.
    """

    def __init__(self, rig: Rig, context, options: GraphOptions | None = None, cameras=None):
        from canopy_stereo.ros.nodes.camera import CameraNode
        from canopy_stereo.ros.nodes.disparity import DisparityNode
        from canopy_stereo.ros.nodes.point_cloud import PointCloudNode
        from canopy_stereo.ros.nodes.rectify import RectifyNode
        from canopy_stereo.ros.nodes.segment import SegmentNode

        self.rig = rig
        self.context = context
        self.options = o = options or GraphOptions()
        if o.executor not in EXECUTOR_CHOICES:
            raise CanopyStereoError(f"unknown executor {o.executor!r}; choose "
                                    f"{' or '.join(EXECUTOR_CHOICES)}")
        self.nodes: dict = {}
        # node -> its executor (per-node), or every node -> the one shared executor (multi)
        self._executors: list = []
        self._shared = (MultiThreadedExecutor(num_threads=o.threads, context=context)
                        if o.executor == "multi" else None)
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        #: the nodes' intra-process bus (None: DDS between them too)
        self.bus = IntraProcessBus() if o.intra_process else None
        common = {"reliability": o.reliability}
        per_node = {
            "rectify_node": o.mounting_parameters(),
            "disparity_node": ({} if o.matcher is None else {"matcher": o.matcher})
            | ({} if o.disparity_threads is None else {"threads": int(o.disparity_threads)})
            # the cloud keeps plant pixels only: match only where the previous masks had plant
            | ({"roi": True} if o.use_mask else {}),
            # nothing waits for every mask unless use_mask: let GrabCut skip frames under load
            # masked: a mask for every frame the matcher matched (and only for those)
            "segment_node": ({"follow_disparity": True} if o.use_mask else {"queue_size": 1})
            | ({"depth_cue": True} if o.segment_depth_cue else {})
            | ({} if o.recut_every is None else {"recut_every": int(o.recut_every)})
            | ({} if o.propagate_scale is None else {"propagate_scale": float(o.propagate_scale)}),
            "point_cloud_node": {"use_mask": bool(o.use_mask), "organized": bool(o.organized)},
        }
        if cameras is not None:
            # free-running cameras: pair within half a frame period at the cameras' rate
            rates = [float(c.get("fps", 0) or 0) for c in cameras]
            if all(r > 0 for r in rates):
                per_node["rectify_node"]["fps"] = min(rates)
        classes = {"rectify_node": RectifyNode, "disparity_node": DisparityNode,
                   "segment_node": SegmentNode, "point_cloud_node": PointCloudNode}
        if o.traits:
            from canopy_stereo.ros.nodes.traits import TraitsNode

            classes["traits_node"] = TraitsNode
            per_node["traits_node"] = {}
        try:
            if cameras is not None and len(cameras) == 1:  # one device with both views (``layout``)
                values = {**common, **cameras[0]}
                if o.frame_prefix and "frame_id" not in values:
                    values["frame_id"] = o.frame_prefix + default_camera_frame("left")
                self._add("stereo_camera", CameraNode, values, rig_params=True)
            elif cameras is not None:
                for side, params in zip(("left", "right"), cameras):
                    values = {"camera_name": side, **common, **params}
                    if o.frame_prefix and "frame_id" not in values:
                        values["frame_id"] = o.frame_prefix + default_camera_frame(side)
                    self._add(f"{side}_camera", CameraNode, values, rig_params=True)  # camera_info
            for name, cls in classes.items():
                if name == "segment_node" and not (o.segment or o.use_mask):
                    continue
                values = {**common, **per_node[name], **o.node_parameters.get(name, {})}
                self._add(name, cls, values, rig_params=name != "segment_node")
        except Exception:
            self.shutdown()
            raise

    def _add(self, key, cls, values: dict, rig_params: bool) -> None:
        overrides = (rig_parameter_overrides(self.rig) if rig_params else []) + parameters_from_dict(values)
        kwargs = dict(context=self.context, namespace=self.options.namespace, intra_process=self.bus,
                      parameter_overrides=overrides, use_global_arguments=True,
                      start_parameter_services=self.options.parameter_services)
        node = cls(node_name=key, **kwargs)
        self.nodes[key] = node
        self.add_node(node)

    def add_node(self, node) -> None:
        """Spin another node (a player, a recorder, a test sink) with the graph: on an
        executor and thread of its own, or on the shared executor with ``executor="multi"``.
        Nodes added after :meth:`spin_in_background` start spinning at once."""
        if self._shared is not None:
            self._shared.add_node(node)
            if not self._executors:
                self._executors.append(self._shared)
            return
        executor = SingleThreadedExecutor(context=self.context)
        executor.add_node(node)
        self._executors.append(executor)
        if self._threads:
            self._start(executor, node.get_name())

    def _start(self, executor, name: str) -> None:
        def spin():
            try:
                while self.context.ok() and not self._stop.is_set():
                    executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down under the executor
                if self.context.ok() and not self._stop.is_set():
                    raise

        thread = threading.Thread(target=spin, name=f"canopy_graph:{name}", daemon=True)
        self._threads.append(thread)
        thread.start()

    @property
    def executors(self) -> list:
        """The executors spinning the graph's nodes (one per node, or the shared one)."""
        return list(self._executors)

    def spin_in_background(self) -> list[threading.Thread]:
        """Spin every executor in a daemon thread (stopped by :meth:`shutdown`); returns the threads."""
        if self._threads:  # already spinning
            return list(self._threads)
        self._stop.clear()
        for executor in self._executors:
            nodes = executor.get_nodes()
            self._start(executor, nodes[0].get_name() if len(nodes) == 1 else "shared")
        return list(self._threads)

    def spin_until_interrupted(self) -> None:
        """Spin in the background and wait in the main thread (where signals arrive) until
        Ctrl-C/SIGTERM (:func:`~canopy_stereo.ros.nodes.base.install_stop_signals`) or shutdown."""
        self.spin_in_background()
        while self.context.ok() and not self._stop.is_set():
            time.sleep(0.1)

    def stats(self) -> dict:
        """Node name -> ``{"counts": ..., "drops": ...}``."""
        return {name: node.stats() for name, node in self.nodes.items()}

    def shutdown(self) -> None:
        """Stop spinning and destroy the nodes (the context stays up)."""
        self._stop.set()
        for thread in self._threads:
            thread.join(timeout=10)
        self._threads.clear()
        for executor in self._executors:
            # rclpy's MultiThreadedExecutor.shutdown neither waits for work already handed to
            # its thread pool (a message take, a callback) nor keeps its guard condition for
            # it: drain the pool first, then shut the executor down, then destroy the nodes
            pool = getattr(executor, "_executor", None)
            if pool is not None and hasattr(pool, "shutdown"):
                pool.shutdown(wait=True)
            executor.shutdown(timeout_sec=30.0)
        self._executors.clear()
        for node in list(self.nodes.values()):
            node.destroy_node()
        self.nodes.clear()
