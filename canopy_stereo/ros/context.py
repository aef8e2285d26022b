"""Isolated rclpy contexts and small helpers for running nodes in-process.

``canopy-stereo run``, the demo, the benchmark and the tests build the whole
graph inside one Python process. Each gets its own :class:`rclpy.context.Context`
on a chosen DDS domain so that several runs (or a live robot on domain 0) do
not see each other's topics.
"""
from __future__ import annotations

import functools
import hashlib
import os
import re
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from canopy_stereo.errors import CanopyStereoError

#: Domains used for private runs: 100 .. 199, clear of the default 0
#: and inside the range every DDS vendor accepts (0..232).
PRIVATE_DOMAIN_BASE = 100
PRIVATE_DOMAIN_COUNT = 100

_reserved: dict[int, tuple[int, int | None]] = {}  # pid -> (domain, the descriptor of its lock file)
_reserve_lock = threading.Lock()


def _domain_lock_dir() -> Path:
    return Path(tempfile.gettempdir()) / f"canopy_stereo_domains-{os.getuid() if hasattr(os, 'getuid') else 0}"


def private_domain_id(pid: int | None = None) -> int:
    """A DDS domain id (``100 .. 199``) for this process's private runs and the node
    processes it starts, not used by any other process on this machine that asked here.

    The first call of a process reserves the first free domain from ``100 + pid mod 100``
    on (an exclusive ``flock`` on a file in the temporary directory, held until the
    process exits) and later calls return it; two test sessions or benchmark runs at the
    same time therefore never share a domain (a pid-derived id alone collided). Where
    locks are unavailable, or every domain is taken, the pid-derived id is returned.
    ``pid`` given: the pid-derived id of that process, no reservation.
    """
    if pid is not None:
        return PRIVATE_DOMAIN_BASE + pid % PRIVATE_DOMAIN_COUNT
    me = os.getpid()
    with _reserve_lock:
        held = _reserved.get(me)
        if held is not None:
            return held[0]
        first = me % PRIVATE_DOMAIN_COUNT
        domain = PRIVATE_DOMAIN_BASE + first
        try:
            import fcntl

            folder = _domain_lock_dir()
            folder.mkdir(mode=0o700, exist_ok=True)
            for k in range(PRIVATE_DOMAIN_COUNT):
                candidate = PRIVATE_DOMAIN_BASE + (first + k) % PRIVATE_DOMAIN_COUNT
                fd = os.open(folder / f"{candidate}.lock", os.O_WRONLY | os.O_CREAT, 0o600)  # held until exit
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:
                    os.close(fd)
                    continue
                _reserved[me] = (candidate, fd)
                return candidate
        except (ImportError, OSError):
            pass
        _reserved[me] = (domain, None)
        return domain


def env_domain_id() -> int:
    """``ROS_DOMAIN_ID`` from the environment (0 when unset or invalid)."""
    try:
        return int(os.environ.get("ROS_DOMAIN_ID", "0"))
    except ValueError:
        return 0


#: GIL switch interval (seconds) for processes that run pipeline nodes.
PIPELINE_SWITCH_INTERVAL_S = 0.001


def tune_thread_switching(interval_s: float = PIPELINE_SWITCH_INTERVAL_S) -> None:
    """Shorten Python's GIL switch interval (default 5 ms) in a node process.

    The heavy kernels (ELAS, triangulation) release the GIL, but each stage
    hand-off must take it back while executor threads run Python code; with
    the default 5 ms interval a frame waits that long at every hand-off.
    Measured on the croton bag (2 cores, ELAS + GrabCut): 5.0 frames/s at 5 ms,
    9.8 frames/s at 1 ms.
    """
    if sys.getswitchinterval() > interval_s:
        sys.setswitchinterval(interval_s)


#: Environment variable overriding :data:`NODE_OPENCV_THREADS` (an integer; 0 = OpenCV's default pool).
OPENCV_THREADS_ENV = "CANOPY_STEREO_OPENCV_THREADS"
#: OpenCV threads of a node process (remap, colour conversion, optical flow, GrabCut).
NODE_OPENCV_THREADS = 1


def tune_opencv_threads(default: int = NODE_OPENCV_THREADS) -> int:
    """One OpenCV thread in a node process (``CANOPY_STEREO_OPENCV_THREADS`` overrides it;
    0 = OpenCV's own pool, one thread per core); returns the count set.

    The graph's parallelism is its processes (and ELAS's own ``threads`` budget): on two
    cores every other node is busy while one remaps, and OpenCV's pool in each of four
    processes only adds hand-offs. Measured on the rectify path (640x480, Plants frames:
    conversion, rectification, skew compensation, messages): 6.0 ms of CPU per pair with one
    thread, 7.6 ms with OpenCV's two (``benchmarks/bench_graph.py`` gives the graph's figures).
    """
    import cv2

    raw = os.environ.get(OPENCV_THREADS_ENV, "").strip()
    n = int(default)
    if raw:
        try:
            n = int(raw)
            if n < 0:
                raise ValueError
        except ValueError:  # a tuning knob: say so, keep the default
            print(f"warning: {OPENCV_THREADS_ENV} must be an integer >= 0, got {raw!r}: using {default}",
                  file=sys.stderr)
            n = int(default)
    cv2.setNumThreads(n if n > 0 else -1)
    return n


#: glibc malloc settings for node processes (bytes): see :func:`tune_memory_allocator`.
PIPELINE_MALLOC_OPTIONS = {"mmap_threshold": 32 << 20, "trim_threshold": 64 << 20, "top_pad": 16 << 20}

_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3  # glibc <malloc.h>
_malloc_tuned = False
_malloc_settings: dict = {}


@functools.lru_cache(maxsize=1)
def _libc():
    """The C library as a ``ctypes.CDLL`` when it is glibc (has ``mallopt`` and ``malloc_trim``), else None."""
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.mallopt.argtypes, libc.mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
        libc.malloc_trim.argtypes, libc.malloc_trim.restype = [ctypes.c_size_t], ctypes.c_int
        return libc
    except (OSError, AttributeError):  # not glibc
        return None


def tune_memory_allocator(mmap_threshold: int = PIPELINE_MALLOC_OPTIONS["mmap_threshold"],
                          trim_threshold: int = PIPELINE_MALLOC_OPTIONS["trim_threshold"],
                          *, top_pad: int = PIPELINE_MALLOC_OPTIONS["top_pad"]) -> bool:
    """Keep the frame-sized buffers of a node process on the heap, and nothing more (glibc only).

    Every frame allocates and frees images, disparity maps, serialized messages
    and point clouds of 0.3 to 20 MB. glibc serves blocks above its mmap
    threshold (128 kB at start, raised adaptively only after the first frees)
    with fresh ``mmap`` calls, so each frame pays thousands of page faults and
    zeroed pages in the kernel, and returns the memory with ``munmap``. Settings:

    * ``mmap_threshold`` 32 MiB: freed frame buffers are reused from the heap;
      anything larger than a frame (a hostile 8000x8000 image) is mapped on its
      own and returned to the system when freed;
    * ``trim_threshold`` 64 MiB with ``top_pad`` 16 MiB: the heap does not shrink
      and grow back every frame (smaller values cost 2-4x the system time);
    * after a refused large message, :func:`release_free_memory` returns what was freed,
      including the tops of the middleware threads' own arenas (glibc keeps those
      below the trim threshold otherwise).

    The previous settings (256 MiB mmap threshold, 1 GiB trim threshold, 256 MiB
    top pad) were as fast but kept up to 1 GiB after one
    oversize message. ``benchmarks/bench_allocator.py`` measures system and user
    time per frame and RSS for glibc's defaults, the previous and these settings
    (croton bag, ELAS, GrabCut, recording, on 2 shared and loaded cores: system
    time 27-32 ms per frame with glibc's defaults, 6-12 ms previous, 6-13 ms now).
    The same effect as the ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``
    and ``MALLOC_TOP_PAD_`` environment variables; those, when set, win.

    Returns True when the settings were applied (False off glibc, or when
    the environment already sets them).
    """
    global _malloc_tuned
    if _malloc_tuned:
        return True
    if any(os.environ.get(k) for k in ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_")):
        return False
    libc = _libc()
    if libc is None:
        return False
    ok = (libc.mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
          and libc.mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1
          and libc.mallopt(_M_TOP_PAD, int(top_pad)) == 1)
    _malloc_tuned = ok
    if ok:
        _malloc_settings.update(trim_threshold=int(trim_threshold), top_pad=int(top_pad))
    return ok


def malloc_trim_available() -> bool:
    """True when :func:`release_free_memory` can return memory (glibc)."""
    return _libc() is not None


#: Trim threshold and top pad (bytes) while :func:`release_free_memory` holds memory low.
RELEASE_TRIM_THRESHOLD = 1 << 20

_release_lock = threading.Lock()
_release_until = 0.0
_restore_timer: threading.Timer | None = None


def release_free_memory(hold_s: float = 0.0) -> bool:
    """Return free heap memory to the system (glibc), now and for ``hold_s`` seconds.

    Now: ``malloc_trim(0)`` (the main heap's top and the free pages of every arena).
    glibc never trims the *top* of a thread's own arena from ``malloc_trim``, only when
    a block there is freed and the top exceeds the trim threshold -- 64 MiB with
    :func:`tune_memory_allocator` -- so a burst received by a middleware thread would
    stay. With ``hold_s > 0`` (and the allocator tuned by :func:`tune_memory_allocator`)
    the trim threshold and top pad drop to :data:`RELEASE_TRIM_THRESHOLD` for that long,
    so every arena shrinks at its next free (the next messages received); then the
    tuned values, and their speed, come back. Costs a few milliseconds; the nodes call
    it after refusing a large message (:func:`canopy_stereo.ros.limits.release_memory_soon`),
    never per frame. Returns True when memory was released now.
    """
    global _release_until, _restore_timer
    libc = _libc()
    if libc is None:
        return False
    if hold_s > 0 and _malloc_tuned:
        with _release_lock:
            _release_until = max(_release_until, time.monotonic() + hold_s)
            if _restore_timer is None:
                libc.mallopt(_M_TOP_PAD, RELEASE_TRIM_THRESHOLD)
                libc.mallopt(_M_TRIM_THRESHOLD, RELEASE_TRIM_THRESHOLD)
                _restore_timer = threading.Timer(hold_s, _restore_allocator)
                _restore_timer.daemon = True
                _restore_timer.start()
    return bool(libc.malloc_trim(0))


def _restore_allocator() -> None:
    """End of a :func:`release_free_memory` hold: trim once more, restore the tuned values."""
    global _restore_timer
    libc = _libc()
    with _release_lock:
        left = _release_until - time.monotonic()
        if left > 0:  # extended meanwhile
            _restore_timer = threading.Timer(left, _restore_allocator)
            _restore_timer.daemon = True
            _restore_timer.start()
            return
        libc.malloc_trim(0)
        libc.mallopt(_M_TRIM_THRESHOLD, _malloc_settings["trim_threshold"])
        libc.mallopt(_M_TOP_PAD, _malloc_settings["top_pad"])
        _restore_timer = None


#: Fast DDS profiles of node processes (see :func:`use_bounded_dds_memory`).
FASTDDS_PROFILES = Path(__file__).resolve().parents[1] / "data" / "fastdds_profiles.xml"

#: Environment that already configures Fast DDS (then :func:`use_bounded_dds_memory` does nothing).
_FASTDDS_USER_SETTINGS = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE",
                          "RMW_FASTRTPS_USE_QOS_FROM_XML", "SKIP_DEFAULT_XML")
_FASTDDS_CWD_FILES = ("DEFAULT_FASTRTPS_PROFILES.xml", "DEFAULT_FASTDDS_PROFILES.xml")


#: Resolved topics of the raw camera images with the default namespace; the profile's readers
#: of these topics listen on UDP (canopy_stereo/data/fastdds_profiles.xml).
RAW_IMAGE_TOPICS = ("/stereo/left/image_raw", "/stereo/right/image_raw")


#: Prefix of the profiles written for other raw image topics (see :func:`use_bounded_dds_memory`).
_GENERATED_PROFILES = "canopy_stereo_fastdds_"


def use_bounded_dds_memory(raw_topics=RAW_IMAGE_TOPICS) -> bool:
    """Make Fast DDS readers free each received sample instead of keeping the largest one.

    rmw_fastrtps gives every data reader a sample pool that grows to the largest
    message ever received and never shrinks (``PREALLOCATED_WITH_REALLOC``): one
    hostile 8000x8000 image leaves 190 MB in each reader that saw it. The
    package's profile (:data:`FASTDDS_PROFILES`: rmw_fastrtps's settings with
    ``DYNAMIC`` reader memory, and an 8 MiB shared-memory segment so that a frame's images
    and camera_infos are not recycled before the local readers take them: with Fast DDS's
    512 kB they were lost and came back by reliable repair hundreds of ms late) is selected
    through ``FASTRTPS_DEFAULT_PROFILES_FILE``
    and ``RMW_FASTRTPS_USE_QOS_FROM_XML=1``; the QoS set in code and by
    ``qos_overrides`` parameters still applies over it. Takes effect when it runs before
    the process's first ``rclpy.init`` (:func:`tune_node_process` is called before it):
    Fast DDS reads its profiles once; a process that created a participant earlier keeps
    Fast DDS's defaults, which for memory are rmw_fastrtps's.

    Does nothing (returns False) when another middleware is selected
    (``RMW_IMPLEMENTATION``) or the user configures Fast DDS already (one of
    ``FASTRTPS_DEFAULT_PROFILES_FILE``, ``FASTDDS_DEFAULT_PROFILES_FILE``,
    ``RMW_FASTRTPS_USE_QOS_FROM_XML``, ``SKIP_DEFAULT_XML`` set, or a
    ``DEFAULT_FASTRTPS_PROFILES.xml`` in the working directory), unless that is the package's
    profile (inherited from a parent process that ran nodes).

    The profile's readers of the raw camera images, which listen on UDP (see the profile), are
    named after ``raw_topics``: for other topics than :data:`RAW_IMAGE_TOPICS` (another
    namespace, remapped inputs) a copy named after them is written to the temporary directory
    (one per set of names) and selected instead.
    """
    if os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp") not in ("rmw_fastrtps_cpp", ""):
        return False
    current = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE", "")
    ours = current == str(FASTDDS_PROFILES) or Path(current).name.startswith(_GENERATED_PROFILES)
    if not ours and (any(k in os.environ for k in _FASTDDS_USER_SETTINGS)
                     or any(os.path.exists(f) for f in _FASTDDS_CWD_FILES)):
        return False
    if not FASTDDS_PROFILES.is_file():
        return False
    profiles = FASTDDS_PROFILES
    if tuple(raw_topics) != RAW_IMAGE_TOPICS:  # another namespace or remapped inputs: profiles named so
        text = FASTDDS_PROFILES.read_text(encoding="utf-8")
        for default, topic in zip(RAW_IMAGE_TOPICS, raw_topics):
            text = text.replace(f'profile_name="{default}"', f'profile_name="{topic}"')
        digest = hashlib.sha1(text.encode()).hexdigest()[:12]
        profiles = Path(tempfile.gettempdir()) / f"{_GENERATED_PROFILES}{digest}.xml"
        try:
            if not profiles.is_file():
                tmp = profiles.with_name(f"{profiles.name}.{os.getpid()}")
                tmp.write_text(text, encoding="utf-8")
                tmp.replace(profiles)
        except OSError:
            profiles = FASTDDS_PROFILES
    os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profiles)
    os.environ["RMW_FASTRTPS_USE_QOS_FROM_XML"] = "1"
    return True


def raw_image_topics(argv, namespace: str = "/stereo") -> tuple[str, str]:
    """The resolved ``left/image_raw`` and ``right/image_raw`` of a node started with ``argv``:
    its ``--ros-args`` namespace (``-r __ns:=/x``) and remappings (``-r left/image_raw:=/cam/image``,
    also node-prefixed ``rectify_node:left/image_raw:=...``) applied, as rcl resolves them."""
    remaps, in_ros, it = {}, False, iter(argv or [])
    for token in it:
        if token == "--ros-args":
            in_ros = True
        elif token == "--":
            in_ros = False
        elif in_ros and token in ("-r", "--remap"):
            rule = next(it, "")
            if ":=" not in rule:
                continue
            source, target = rule.split(":=", 1)
            if ":" in source:  # node-prefixed rule
                source = source.split(":", 1)[1]
            if source == "__ns":
                namespace = target
            else:
                remaps[source] = target
    ns = "/" + namespace.strip("/") if namespace.strip("/") else ""

    def resolve(name: str) -> str:
        target = remaps.get(name, remaps.get(f"{ns}/{name}", name))
        return target if target.startswith("/") else f"{ns}/{target}"

    return resolve("left/image_raw"), resolve("right/image_raw")


def tune_node_process(argv=None) -> None:
    """Process settings for running pipeline nodes: :func:`tune_thread_switching`,
    :func:`tune_opencv_threads`, :func:`tune_memory_allocator` and :func:`use_bounded_dds_memory` (its raw image readers
    named after the topics ``argv``'s ``--ros-args`` resolve them to: :func:`raw_image_topics`)."""
    tune_thread_switching()
    tune_opencv_threads()
    tune_memory_allocator()
    use_bounded_dds_memory(raw_image_topics(argv) if argv is not None else RAW_IMAGE_TOPICS)


def init_ros(argv, *, context=None, domain_id: int | None = None) -> None:
    """``rclpy.init`` for an executable's command line, with its problems as one line.

    The ``--params-file`` files of ``argv``'s ``--ros-args`` are checked first
    (:func:`~canopy_stereo.ros.params.check_parameter_file`: missing, unreadable, not UTF-8,
    not YAML, not shaped like a parameter file); anything rcl still refuses (a list mixing
    types, a malformed ``-p`` or ``-r`` rule) is raised as :class:`CanopyStereoError` with
    rcl's reason, without its source locations, and rcl's own log line is held back. No
    signal handlers are installed (executables install :func:`install_stop_signals`).
    """
    from canopy_stereo.ros.params import check_parameter_file, parameter_files

    for path in parameter_files(argv):
        check_parameter_file(path)
    kwargs = {} if domain_id is None else {"domain_id": int(domain_id)}
    try:
        with _c_stderr_held():
            rclpy.init(args=list(argv), context=context,
                       signal_handler_options=rclpy.signals.SignalHandlerOptions.NO, **kwargs)
    except _rclpy.RCLError as exc:
        raise CanopyStereoError(rcl_error_reason(str(exc))) from None


def strip_ros_args(argv) -> list[str]:
    """``argv`` without its ``--ros-args`` sections (rclpy's ``remove_ros_args``), for an
    executable's own argument parser; a bad ``--params-file`` or ``--ros-args`` is raised as
    :class:`CanopyStereoError` in one line, as :func:`init_ros` does."""
    from rclpy.utilities import remove_ros_args

    from canopy_stereo.ros.params import check_parameter_file, parameter_files

    for path in parameter_files(argv):
        check_parameter_file(path)
    try:
        with _c_stderr_held():
            return list(remove_ros_args(list(argv)))
    except _rclpy.RCLError as exc:
        raise CanopyStereoError(rcl_error_reason(str(exc))) from None


def parse_executable_args(prog: str, parser, argv):
    """``parser``'s options of the executable ``prog``'s command line ``argv`` (``argv[0]`` the
    program; the ``--ros-args`` sections left out by :func:`strip_ros_args`), or None after
    printing ``<prog>: error: <reason>`` for a bad ``--params-file`` or ``--ros-args`` (the
    executable then exits with status 2). argparse's own usage errors exit with 2 as always."""
    try:
        return parser.parse_args(strip_ros_args(argv)[1:])
    except CanopyStereoError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return None


def init_executable_ros(prog: str, argv) -> bool:
    """:func:`init_ros` for the executable ``prog``: False after printing ``<prog>: error: <reason>``
    for a bad ``--params-file`` or ``--ros-args`` (the executable then exits with status 2)."""
    try:
        init_ros(argv)
    except CanopyStereoError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return False
    return True


def rcl_error_reason(text: str) -> str:
    """rcl's error text as one readable line: source locations (``, at /x/y.c:12``) removed,
    a parameter file's problem as ``parameter file PATH: reason``."""
    text = re.sub(r",? at /\S+:\d+", "", " ".join(text.split())).strip()
    for prefix in ("failed to initialize rcl: ", "Failed to parse ROS arguments: "):
        text = text.removeprefix(prefix)
    m = re.match(r"Couldn't parse params file: '--params-file (.*?)'\. Error: (.*)", text)
    if m:
        return f"parameter file {m.group(1)}: {m.group(2)}"
    m = re.match(r"Couldn't parse (.*?): '(.*?)'\. Error: (.*)", text)
    if m:
        return f"invalid --ros-args {m.group(1)} {m.group(2)!r}: {m.group(3)}"
    return text


@contextmanager
def _c_stderr_held():
    """Send what C code writes to file descriptor 2 to a temporary file while the block runs;
    written out afterwards when the block succeeds, dropped when it raises (rcl logs its
    own line for a command line it refuses, which the caller reports in its words)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no usable stderr: nothing to hold
        yield
        return
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        ok = False
        try:
            yield
            ok = True
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            if ok:
                held.seek(0)
                data = held.read()
                if data:
                    os.write(2, data)


@contextmanager
def ros_context(domain_id: int | None = None, localhost_only: bool = True, *, args=None):
    """An initialised rclpy context, shut down on exit.

    Args:
        domain_id: DDS domain (default: :func:`private_domain_id`).
        localhost_only: keep discovery on this machine
            (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless already set).
        args: command line whose ``--ros-args`` apply to every node of the
            context (default: none, so the host program's ``sys.argv`` is ignored).
    """
    if localhost_only:
        os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    tune_node_process()
    context = Context()
    rclpy.init(args=list(args or []), context=context,
               domain_id=private_domain_id() if domain_id is None else int(domain_id),
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        yield context
    finally:
        if context.ok():
            context.try_shutdown()


def wait_for(predicate, timeout_s: float, *, poll_s: float = 0.01) -> bool:
    """Poll ``predicate()`` until it is true or ``timeout_s`` passes; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return bool(predicate())
        time.sleep(poll_s)


def wait_for_subscribers(publishers, timeout_s: float = 10.0, *, count: int = 1) -> bool:
    """Wait until every publisher has at least ``count`` matched subscriptions."""
    return wait_for(lambda: all(p.get_subscription_count() >= count for p in publishers), timeout_s)
