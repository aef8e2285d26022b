"""Transforms from ``/tf`` and ``/tf_static`` for a node: where was the camera at a stamp?

:class:`TransformListener` looks transforms up at a message's stamp, interpolated, as
octomap_server and MoveIt do:

* on a ROS install (``tf2_ros`` importable) through ``tf2_ros.Buffer`` and
  ``tf2_ros.TransformListener``;
* without tf2_ros (a pip install of rclpy) through the package's own
  :class:`~canopy_stereo.geometry.tf_buffer.TransformBuffer` (slerp + lerp, the same rules),
  fed by subscriptions to ``/tf`` and ``/tf_static`` with tf2_ros's listener QoS. That
  needs the ``tf2_msgs`` Python package (any ROS install has it; it is not on PyPI: the
  tests build it from its ``.msg`` with ``test/support/build_tf2_msgs.py``).

With neither, :class:`TransformListener` raises a :class:`CanopyStereoError` saying that only
the pose topic works.
"""
from __future__ import annotations

import threading

import numpy as np
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.tf_buffer import TransformBuffer, TransformLookupError
from canopy_stereo.ros.convert import stamp_to_ns
from canopy_stereo.ros.tf import TF_STATIC_TOPIC, msg_to_transform, tf_message_class

TF_TOPIC = "/tf"

#: tf2_ros's listener QoS: ``/tf`` reliable volatile, ``/tf_static`` reliable transient local, depth 100.
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)


class TransformListener:
    """Listen to ``/tf`` + ``/tf_static`` for ``node``; :meth:`lookup` at any stamp.

    Args:
        node: the rclpy node that subscribes.
        cache_s: seconds of history kept (tf2's cache time).
        backend: ``"auto"`` (tf2_ros when importable), ``"tf2_ros"`` or ``"canopy_stereo"``.

    Attributes:
        backend: the backend in use.
        received: transforms received (own backend only; tf2_ros keeps its own count).
    """

    def __init__(self, node, *, cache_s: float = 10.0, backend: str = "auto"):
        if backend not in ("auto", "tf2_ros", "canopy_stereo"):
            raise CanopyStereoError(f"unknown TF backend {backend!r}")
        self.received = 0
        self._lock = threading.Lock()
        if backend in ("auto", "tf2_ros"):
            try:
                import tf2_ros
            except ImportError:
                if backend == "tf2_ros":
                    raise CanopyStereoError("tf2_ros is not installed") from None
            else:
                from rclpy.duration import Duration

                self.backend = "tf2_ros"
                self._tf2 = tf2_ros
                self._buffer = tf2_ros.Buffer(cache_time=Duration(nanoseconds=int(cache_s * 1e9)), node=node)
                # spin_thread: transforms are taken in a thread of their own, never queued
                # behind the node's heavy callbacks (a fusion step), as tf2_ros does by default
                self._listener = tf2_ros.TransformListener(self._buffer, node, spin_thread=True)
                return
        cls = tf_message_class()
        if cls is None:
            raise CanopyStereoError("poses from TF need tf2_ros or tf2_msgs (any ROS 2 install has them; "
                                    "they are not on PyPI): without them only the pose topic works")
        self.backend = "canopy_stereo"
        self._buffer = TransformBuffer(cache_s=cache_s)
        # a node and executor of its own, spun in a thread (as tf2_ros's spin_thread): the
        # transforms keep flowing while the owner's executor runs a long callback
        self._node = Node(f"{node.get_name()}_tf_listener", namespace=node.get_namespace(),
                          context=node.context, start_parameter_services=False)
        self._subs = [self._node.create_subscription(cls, TF_TOPIC, lambda m: self._on(m, False), TF_QOS),
                      self._node.create_subscription(cls, TF_STATIC_TOPIC, lambda m: self._on(m, True),
                                                     TF_STATIC_QOS)]
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(self._node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name="tf_listener", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        try:
            while not self._stop.is_set() and self._node.context.ok():
                self._executor.spin_once(timeout_sec=0.05)
        except Exception:  # noqa: BLE001 - the context was shut down under the executor
            if not self._stop.is_set() and self._node.context.ok():
                raise

    def close(self) -> None:
        """Stop listening (the own backend's thread and node; tf2_ros's listener is unregistered)."""
        if self.backend == "tf2_ros":
            self._listener.unregister()
            return
        self._stop.set()
        self._thread.join(timeout=5)
        self._executor.shutdown(timeout_sec=1)
        self._node.destroy_node()

    def _on(self, msg, static: bool) -> None:
        with self._lock:
            for t in msg.transforms:
                parent, child, T = msg_to_transform(t)
                try:
                    self._buffer.set_transform(parent.lstrip("/"), child.lstrip("/"), T,
                                               stamp_to_ns(t.header.stamp), static=static)
                except CanopyStereoError:
                    continue  # a malformed transform (NaN, one frame twice) is not kept
                self.received += 1

    def lookup(self, target: str, source: str, *, stamp_ns: int) -> np.ndarray:
        """``T_target_source`` (4x4, metres) at ``stamp_ns``, interpolated; raises
        :class:`~canopy_stereo.geometry.tf_buffer.TransformLookupError` naming why not
        (unknown frame, not connected, extrapolation into the past/future)."""
        if self.backend == "tf2_ros":
            from rclpy.time import Time

            try:
                msg = self._buffer.lookup_transform(target, source, Time(nanoseconds=int(stamp_ns)))
            except self._tf2.TransformException as exc:
                raise TransformLookupError(str(exc)) from None
            return msg_to_transform(msg)[2]
        with self._lock:
            return self._buffer.lookup(target, source, stamp_ns=int(stamp_ns))
