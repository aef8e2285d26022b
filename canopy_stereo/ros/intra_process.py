"""Intra-process delivery between the nodes of one process (``canopy_graph``, ``canopy-stereo run``).

rclpy has no intra-process communication: a message from one node to another node of
the same process is converted to C, serialized by Fast DDS, handed through the
participant, deserialized and converted back to Python, and both ends hold the GIL
while they do it. For the graph's ~4 MB per frame (rectified images, disparity, mask)
that was about 40 % of the time the one-process graph held the GIL (py-spy ``--gil``,
640x480 at 30 frames/s), so its nodes waited for each other although the cores
were free.

An :class:`IntraProcessBus` shared by the nodes of a
:class:`~canopy_stereo.ros.graph.CanopyGraph` passes the message *object* instead,
as rclcpp's intra-process manager passes a ``unique_ptr``/``shared_ptr``:

* a node's publisher registers its resolved topic name (:meth:`IntraProcessBus.register_publisher`);
  every ``publish`` still goes to DDS (for other processes, recorders, RViz; with no
  subscriber there it costs the serialization only) and then to the bus;
* a node subscribing to a topic that a node *of the bus* publishes gets a
  :class:`LocalSubscription` instead of a DDS subscription: messages wait in a keep-last
  queue of the subscription's depth (as a reliable keep-last DDS reader: when the
  node falls behind, the oldest are replaced) and a guard condition wakes the node's
  own executor, so the callback runs in the node's thread, one at a time, as before;
* topics that no node of the bus publishes (raw camera images from a bag player or
  another process) and latched topics stay DDS subscriptions.

Messages are shared, not copied: the publisher and every local subscriber see the
same object, so a node must not modify a message after publishing it or while
handling it (the package's nodes build a new message per frame and only read theirs).
Publishers must be created before the subscriptions that should find them; in the
graph data flows one way (cameras -> rectify -> disparity -> segment -> point cloud),
which is the order the nodes are built in.
"""
from __future__ import annotations

import threading
from collections import deque


class LocalSubscription:
    """One node's subscription to a topic of the bus (see the module docstring).

    Attributes:
        topic_name: resolved topic name (``/stereo/left/image_rect``).
        depth: keep-last queue length (messages).
        replaced: messages dropped unread because ``depth`` newer ones arrived first.
    """

    def __init__(self, bus: IntraProcessBus, node, topic_name: str, callback, depth: int):
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self.bus, self.topic_name, self.depth = bus, topic_name, int(depth)
        self.replaced = 0
        self._callback = callback
        self._queue: deque = deque()
        self._lock = threading.Lock()
        self._guard = node.create_guard_condition(self._drain)
        self._closed = False

    def deliver(self, msg) -> None:
        """Queue ``msg`` (from any thread) and wake the node's executor."""
        with self._lock:
            if self._closed:
                return
            self._queue.append(msg)
            if len(self._queue) > self.depth:
                self._queue.popleft()
                self.replaced += 1
        try:
            self._guard.trigger()
        except Exception:  # noqa: BLE001 - the node is being destroyed under the publisher
            pass

    def _drain(self) -> None:
        """Guard-condition callback (the node's executor thread): handle every queued message
        in order (triggers that came together wake the executor once)."""
        while True:
            with self._lock:
                if not self._queue:
                    return
                msg = self._queue.popleft()
            self._callback(msg)

    def pending(self) -> int:
        """Messages waiting."""
        with self._lock:
            return len(self._queue)

    def get_publisher_count(self) -> int:
        """Publishers of the topic on the bus (the DDS subscription's method of the same name)."""
        return self.bus.publisher_count(self.topic_name)

    def close(self) -> None:
        """Stop receiving; waiting messages are discarded."""
        with self._lock:
            self._closed = True
            self._queue.clear()
        self.bus.unsubscribe(self)


class IntraProcessBus:
    """Topic name -> the local subscriptions of one process's nodes (thread-safe)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._publishers: dict[str, int] = {}
        self._subscriptions: dict[str, tuple[LocalSubscription, ...]] = {}

    def register_publisher(self, topic_name: str) -> None:
        """A node of the bus publishes ``topic_name`` (resolved)."""
        with self._lock:
            self._publishers[topic_name] = self._publishers.get(topic_name, 0) + 1

    def unregister_publisher(self, topic_name: str) -> None:
        with self._lock:
            n = self._publishers.get(topic_name, 0) - 1
            if n > 0:
                self._publishers[topic_name] = n
            else:
                self._publishers.pop(topic_name, None)

    def publisher_count(self, topic_name: str) -> int:
        """Publishers of ``topic_name`` registered on the bus."""
        with self._lock:
            return self._publishers.get(topic_name, 0)

    def subscribe(self, node, topic_name: str, callback, depth: int) -> LocalSubscription:
        """A :class:`LocalSubscription` of ``node`` to ``topic_name`` calling ``callback(msg)``
        in ``node``'s executor."""
        sub = LocalSubscription(self, node, topic_name, callback, depth)
        with self._lock:
            self._subscriptions[topic_name] = self._subscriptions.get(topic_name, ()) + (sub,)
        return sub

    def unsubscribe(self, sub: LocalSubscription) -> None:
        with self._lock:
            subs = tuple(s for s in self._subscriptions.get(sub.topic_name, ()) if s is not sub)
            if subs:
                self._subscriptions[sub.topic_name] = subs
            else:
                self._subscriptions.pop(sub.topic_name, None)

    def deliver(self, topic_name: str, msg) -> int:
        """Hand ``msg`` to every local subscription of ``topic_name``; returns how many."""
        with self._lock:
            subs = self._subscriptions.get(topic_name, ())
        for sub in subs:
            sub.deliver(msg)
        return len(subs)

    def subscription_count(self, topic_name: str) -> int:
        """Local subscriptions of ``topic_name``."""
        with self._lock:
            return len(self._subscriptions.get(topic_name, ()))
