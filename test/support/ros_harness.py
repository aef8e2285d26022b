"""Multi-process ROS test harness: the package's executables in processes of their own.

The product is run as users run it (``ros2 run canopy_stereo <node>``, one process per
node); tests do the same:

* :class:`ProcessGroup` starts executables (the console scripts installed beside the
  test's Python, else ``python -m <module>``) on one private DDS domain, with
  ``--ros-args`` (parameter files, ``-p name:=value`` as on a command line), keeps
  each process's output in a log file, and stops them all (SIGINT, then SIGKILL)
  at the end; :meth:`ProcessGroup.start_graph` starts the processing nodes.
* :class:`Harness` is the test's in-process ROS side (the ``harness`` fixture of
  conftest.py): a helper node and the nodes under test, spun by one executor in a
  background thread. :class:`Probe` is a Harness on a context of its own: it publishes like a
  camera driver (system-default QoS: reliable, keep last 10) and subscribes like a
  foreign consumer, with any QoS, receiving raw CDR bytes (no deserialization of
  5 MB clouds in the test process) with their arrival times.
* :func:`feed_pairs` publishes stereo pairs at a fixed rate and returns when each
  pair left.

The ``ros_processes`` fixture (conftest.py) gives a :class:`ProcessGroup` on the
test's private domain and cleans up after the test.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: executable -> module with ``main`` (used when the console script is not installed)
MODULES = {
    "camera_node": "canopy_stereo.ros.nodes.camera",
    "rectify_node": "canopy_stereo.ros.nodes.rectify",
    "disparity_node": "canopy_stereo.ros.nodes.disparity",
    "segment_node": "canopy_stereo.ros.nodes.segment",
    "point_cloud_node": "canopy_stereo.ros.nodes.point_cloud",
    "fusion_node": "canopy_stereo.ros.fusion_node",
    "traits_node": "canopy_stereo.ros.nodes.traits",
    "bag_play": "canopy_stereo.ros.player",
    "bag_record": "canopy_stereo.ros.recorder",
    "canopy_graph": "canopy_stereo.ros.canopy_graph",
}

#: The processing nodes of the graph, in data-flow order.
PROCESSING_NODES = ("rectify_node", "disparity_node", "segment_node", "point_cloud_node")


@contextmanager
def killed_at_exit(*procs: subprocess.Popen):
    """Run the block; then SIGKILL and reap each of ``procs`` still running (a failed
    assertion or a timeout inside the block leaves no process behind)."""
    try:
        yield
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


def executable_command(name: str) -> list[str]:
    """How to start executable ``name``: its console script, else ``python -m module``."""
    script = Path(sys.executable).parent / name
    if script.is_file() and os.access(script, os.X_OK):
        return [str(script)]
    if name not in MODULES:
        raise ValueError(f"unknown executable {name!r}")
    return [sys.executable, "-m", MODULES[name]]


def ros_value(value) -> str:
    """A Python value as a ``-p name:=value`` command-line value (YAML)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(ros_value(v) for v in value) + "]"
    return str(value)


class NodeProcess:
    """One running executable; output goes to ``log_path``."""

    def __init__(self, name: str, argv: list[str], env: dict, log_path: Path):
        self.name, self.argv, self.log_path = name, argv, log_path
        self._log = open(log_path, "wb")
        self.proc = subprocess.Popen(argv, env=env, stdout=self._log, stderr=subprocess.STDOUT,
                                     stdin=subprocess.DEVNULL, cwd=REPO)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def log(self) -> str:
        """Everything the process printed so far."""
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def stop(self, timeout_s: float = 20.0) -> int:
        """SIGINT (a node's Ctrl-C), SIGKILL after ``timeout_s``; returns the exit status."""
        if self.alive():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self._log.close()
        return self.proc.returncode


class ProcessGroup:
    """Executables started on one DDS domain (``domain_id``), stopped together.

    Args:
        domain_id: ``ROS_DOMAIN_ID`` of every process (discovery stays on this host).
        log_dir: where each process's output is written (``<name>.log``).
    """

    def __init__(self, domain_id: int, log_dir: Path):
        self.domain_id = int(domain_id)
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.processes: list[NodeProcess] = []
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain_id),
                        ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        self.env.pop("ROS_LOCALHOST_ONLY", None)

    def start(self, executable: str, *args, params: dict | None = None, params_files=(),
              name: str | None = None, namespace: str | None = None, ros_args=()) -> NodeProcess:
        """Start ``executable ARGS --ros-args [--params-file F]... [-p k:=v]... [-r __node:=NAME]``."""
        argv = executable_command(executable) + [str(a) for a in args]
        ros = [str(a) for a in ros_args]
        for f in params_files:
            ros += ["--params-file", str(f)]
        for key, value in (params or {}).items():
            ros += ["-p", f"{key}:={ros_value(value)}"]
        if name:
            ros += ["-r", f"__node:={name}"]
        if namespace:
            ros += ["-r", f"__ns:={namespace}"]
        if ros:
            argv += ["--ros-args"] + ros
        label = name or executable
        n = sum(1 for p in self.processes if p.name == label)
        proc = NodeProcess(label, argv, self.env, self.log_dir / f"{label}{'-' + str(n) if n else ''}.log")
        self.processes.append(proc)
        return proc

    def start_launched(self, commands) -> list[NodeProcess]:
        """Start the node commands of an evaluated launch file (:func:`launch_eval.evaluate`)."""
        out = []
        for cmd in commands:
            argv = executable_command(cmd.executable) + list(cmd.arguments)
            if cmd.ros_args:
                argv += ["--ros-args"] + list(cmd.ros_args)
            label = cmd.name or cmd.executable
            proc = NodeProcess(label, argv, self.env, self.log_dir / f"{label}.log")
            self.processes.append(proc)
            out.append(proc)
        return out

    def start_graph(self, rig_file, *, nodes=PROCESSING_NODES, params: dict | None = None,
                    common: dict | None = None) -> dict:
        """Start the processing nodes, one process each, with the rig file; ``params``:
        node -> extra parameters, ``common``: parameters of every node. As in the launch
        file and ``canopy_graph``, segment_node segments the newest image (queue_size 1)
        unless point_cloud_node uses the masks, and then disparity_node matches only in the
        plant region of the previous masks (``roi``) and segment_node segments the frames it
        matched (``follow_disparity``)."""
        out = {}
        use_mask = bool((params or {}).get("point_cloud_node", {}).get("use_mask", False))
        defaults = {"segment_node": {"follow_disparity": True} if use_mask else {"queue_size": 1},
                    "disparity_node": {"roi": True} if use_mask else {}}
        for node in nodes:
            values = {**(common or {}), **defaults.get(node, {}), **(params or {}).get(node, {})}
            files = [] if node == "segment_node" else [rig_file]
            out[node] = self.start(node, params_files=files, params=values)
        return out

    def check_alive(self) -> None:
        """Raise AssertionError with the log of any process that exited."""
        dead = [p for p in self.processes if not p.alive()]
        if dead:
            raise AssertionError("\n".join(f"{p.name} exited with {p.proc.returncode}:\n{p.log()[-3000:]}"
                                           for p in dead))

    def logs(self) -> str:
        return "\n".join(f"----- {p.name}\n{p.log()[-4000:]}" for p in self.processes)

    def stop_all(self) -> dict:
        """Stop every process (reverse start order); returns name -> exit status."""
        codes = {}
        for p in reversed(self.processes):
            codes[p.name] = p.stop()
        return codes


@dataclass
class Received:
    """Messages of one subscription: ``(arrival monotonic s, header stamp ns, CDR bytes)``."""

    topic: str
    items: list = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def stamps(self) -> list[int]:
        with self.lock:
            return [s for _, s, _ in self.items]

    def __len__(self) -> int:
        with self.lock:
            return len(self.items)


class Harness:
    """The test's in-process ROS side on one context: a helper node (``test_helper`` in
    ``/stereo``) and every node :meth:`add`-ed, spun by one ``SingleThreadedExecutor`` in a
    background thread. The ``harness`` fixture (conftest.py) gives one on the test
    process's private DDS domain; :meth:`close` stops the thread and destroys the nodes.

    Args:
        ctx: an initialised rclpy context (e.g. from ``canopy_stereo.ros.context.ros_context``).
        name: the helper node's name.
        namespace: the helper node's namespace (relative topics resolve under it).
        timeout_s: how long :meth:`connect` and :meth:`wait_publishers` wait, seconds.
    """

    def __init__(self, ctx, name: str = "test_helper", namespace: str = "/stereo", timeout_s: float = 20.0):
        import rclpy.node
        from rclpy.executors import SingleThreadedExecutor

        self.ctx = self.context = ctx
        self.timeout_s = float(timeout_s)
        self.executor = SingleThreadedExecutor(context=ctx)  # nothing left running after close()
        self.helper = self.node = rclpy.node.Node(name, context=ctx, namespace=namespace,
                                                  start_parameter_services=False)
        self.executor.add_node(self.helper)
        self.nodes = [self.helper]
        self.received = {}
        self.subscriptions = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop.is_set() and self.ctx.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - context shut down under the executor
                if not self._stop.is_set():
                    raise

    def add(self, node):
        """Spin ``node`` too (destroyed by :meth:`close`); returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def remove(self, node):
        """Stop spinning ``node`` (the caller destroys it)."""
        self.executor.remove_node(node)
        self.nodes.remove(node)

    def publisher(self, msg_type, topic):
        """A helper publisher with the nodes' input QoS (:func:`canopy_stereo.ros.qos.publisher_qos`)."""
        from canopy_stereo.ros.qos import publisher_qos

        return self.helper.create_publisher(msg_type, topic, publisher_qos())

    def collect(self, msg_type, topic):
        """A list that every message on ``topic`` is appended to (recording QoS)."""
        from canopy_stereo.ros.qos import recording_qos

        self.received[topic] = []
        sub = self.helper.create_subscription(msg_type, topic, self.received[topic].append, recording_qos())
        self.subscriptions[topic] = sub
        return self.received[topic]

    def wait_publishers(self, *topics):
        """Assert that every collected ``topic`` has a publisher within the timeout."""
        from canopy_stereo.ros.context import wait_for as ros_wait_for

        subs = [self.subscriptions[t] for t in topics]
        assert ros_wait_for(lambda: all(s.get_publisher_count() >= 1 for s in subs), self.timeout_s), \
            "publishers did not connect"

    def connect(self, *pubs):
        """Assert that every publisher in ``pubs`` has a subscriber within the timeout."""
        from canopy_stereo.ros.context import wait_for_subscribers

        assert wait_for_subscribers(pubs, self.timeout_s), "subscribers did not connect"

    def close(self):
        self._stop.set()
        self._thread.join(timeout=10)
        for node in reversed(self.nodes):
            node.destroy_node()
        self.nodes.clear()
        self.executor.shutdown(timeout_sec=1)


class Probe(Harness):
    """A :class:`Harness` on a context of its own on ``domain_id``: publishers like a camera
    driver and foreign subscribers (raw CDR bytes with their arrival times).

    Spins in a background thread; :meth:`close` stops it and shuts its context down.
    """

    def __init__(self, domain_id: int, namespace: str = "/stereo", name: str = "test_probe"):
        from canopy_stereo.ros.context import ros_context

        self._ctx_manager = ros_context(domain_id)
        super().__init__(self._ctx_manager.__enter__(), name=name, namespace=namespace)

    def publisher(self, msg_type, topic: str, qos=None):
        """A publisher with ``qos`` (default: the system-default a driver uses, reliable keep last 10)."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        qos = qos or QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        return self.node.create_publisher(msg_type, topic, qos)

    def subscribe(self, msg_type, topic: str, qos=None) -> Received:
        """A raw subscription with ``qos`` (default: reliable keep last 10) recording stamps."""
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        from canopy_stereo.ros.recorder import header_stamp_from_cdr

        qos = qos or QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        received = Received(topic)

        def on_msg(data):
            data = bytes(data)
            with received.lock:
                received.items.append((time.monotonic(), header_stamp_from_cdr(data), data))

        sub = self.node.create_subscription(msg_type, topic, on_msg, qos, raw=True)
        received.subscription = sub
        return received

    def close(self):
        super().close()
        self._ctx_manager.__exit__(None, None, None)


def wait_for(predicate, timeout_s: float, poll_s: float = 0.05, group: ProcessGroup | None = None) -> bool:
    """Poll ``predicate()`` until true or ``timeout_s``; with ``group``, fail early when a
    process died."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if group is not None:
            group.check_alive()
        if time.monotonic() >= deadline:
            return bool(predicate())
        time.sleep(poll_s)


def croton_frames():
    """The bundled croton bag's (left, right) bgr8 640x480 frames."""
    from canopy_stereo.bag import BagReader
    from canopy_stereo.ros.bundled import bundled_bag
    from canopy_stereo.ros.convert import msg_to_image

    bag = BagReader(bundled_bag("croton"))
    lefts = [msg_to_image(m).copy() for _, m in bag.read("/stereo/left/image_raw")]
    rights = [msg_to_image(m).copy() for _, m in bag.read("/stereo/right/image_raw")]
    return list(zip(lefts, rights))


def feed_pairs(pub_left, pub_right, frames, stamps_ns, rate_hz: float, right_offset_ns: int = 4_000_000,
               stop: threading.Event | None = None, make_msg=None) -> dict:
    """Publish ``frames[k % len]`` stamped ``stamps_ns[k]`` (right ``+right_offset_ns``) at
    ``rate_hz``; returns left stamp -> monotonic time the pair's right image left.
    ``make_msg(image, frame_id)`` builds each message (default: a bgr8 Image)."""
    from canopy_stereo.ros.convert import image_to_msg

    if make_msg is None:
        def make_msg(image, frame_id):
            return image_to_msg(image, "bgr8", stamp_ns=0, frame_id=frame_id)

    msgs = [(make_msg(left, "left_camera"), make_msg(right, "right_camera")) for left, right in frames]
    sent = {}
    t0 = time.monotonic()
    for k, stamp in enumerate(stamps_ns):
        target = t0 + k / rate_hz
        delay = target - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if stop is not None and stop.is_set():
            break
        left, right = msgs[k % len(msgs)]
        rs = stamp + right_offset_ns
        left.header.stamp.sec, left.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        right.header.stamp.sec, right.header.stamp.nanosec = divmod(rs, 1_000_000_000)
        pub_left.publish(left)
        pub_right.publish(right)
        sent[stamp] = time.monotonic()
    return sent


def record_with_bag_record(out: Path, messages, *, args=(), timeout_s: float = 30.0) -> str:
    """Run the ``bag_record`` executable (its own process, a private domain) recording the
    topics of ``messages`` (``[(topic, type name, CDR bytes), ...]``, e.g. a bag's messages)
    into ``out`` with the further command-line ``args`` (``["--rig", RIG]``); publish the
    messages in order (reliable, depth 10), then stop it with SIGINT. Returns its stderr;
    raises AssertionError when it does not subscribe or does not exit with 0."""
    from rclpy.node import Node

    from canopy_stereo.bag.msgdefs import message_class
    from canopy_stereo.ros.context import private_domain_id, ros_context
    from canopy_stereo.ros.qos import publisher_qos

    domain = private_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    topics = list(dict.fromkeys(topic for topic, _, _ in messages))
    proc = subprocess.Popen(executable_command("bag_record") + ["-o", str(out), *topics, *map(str, args)],
                            env=env, stderr=subprocess.PIPE, text=True)
    with killed_at_exit(proc):
        with ros_context(domain) as ctx:
            node = Node("bag_record_feeder", context=ctx, start_parameter_services=False)
            pubs = {}
            for topic, type_name, _ in messages:
                if topic not in pubs:
                    pubs[topic] = node.create_publisher(message_class(type_name), topic,
                                                        publisher_qos("reliable", 10))
            assert wait_for(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), timeout_s), \
                "bag_record did not subscribe"
            time.sleep(0.2)
            for topic, _, data in messages:
                pubs[topic].publish(data)
                time.sleep(0.05)
            time.sleep(0.5)
            node.destroy_node()
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=timeout_s)
    assert proc.returncode == 0, err
    return err
