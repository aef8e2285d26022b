"""Row-band parallelism for the nogil numba kernels.

The heavy kernels (support candidates, dense matching, the left-right check and the
filters: small-segment removal, gap interpolation by rows then by column bands, adaptive
mean) compute independent image rows (small-segment removal unites its bands' segments
in one short serial pass). They are compiled with ``nogil=True`` and take a ``[row_start, row_stop)``
range; :func:`run_row_bands` splits the rows into contiguous bands and runs them
on a shared thread pool. Each row is computed by exactly one band with the same
code, so the output does not depend on the number of threads.

The thread count follows :func:`numba.get_num_threads` (set it with
:func:`numba.set_num_threads` or ``NUMBA_NUM_THREADS``). Plain threads are used
instead of ``prange`` because an OpenMP team that spin-waits collapses when the
cores are shared with other processes (measured on a loaded 2-core machine: the
2-thread ``prange`` version ran 4x slower than 1 thread), and because ``parallel=True``
multiplies the compile time of a cold cache.

:func:`budget_threads` turns a thread *budget* into a thread count for one frame: the
automatic budget (:data:`AUTO_THREADS`, ``disparity_node``'s default) runs frames up to
:data:`ONE_THREAD_MAX_PIXELS` (640x480-class) on one thread and larger ones (1280x720)
on every core. Measured on this 2-vCPU machine (loaded): a second thread makes a frame's
CPU time 5-13 % (640x480) to 20-50 % (1280x720) larger (the two vCPUs share a core), so at
640x480, where the 4-process graph keeps both cores busy, it only takes CPU from the other
nodes; at 1280x720, where the graph leaves the second core partly idle, it cut ELAS's wall
time from 128 to 102 ms (fastest of 10 frames, load 2.5; nothing under a load of 10-15).
"""
from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numba

#: Bands per thread: a little over-splitting evens out rows of unequal cost.
BANDS_PER_THREAD = 2

_pools: dict[int, ThreadPoolExecutor] = {}
_local = threading.local()
_pools_lock = threading.Lock()


#: The automatic thread budget (see :func:`budget_threads`).
AUTO_THREADS = -1
#: Largest frame (pixels) the automatic budget matches on one thread: 640x480 (0.31 MP)
#: and the Middlebury 2014 quarter-size scenes (up to 741x497) are below, 1280x720
#: (0.92 MP) above.
ONE_THREAD_MAX_PIXELS = 500_000


def budget_threads(budget: int, *, pixels: int, limit: int) -> int:
    """Threads to match a frame of ``pixels`` with, under a thread ``budget``:
    :data:`AUTO_THREADS` (-1): 1 up to :data:`ONE_THREAD_MAX_PIXELS`, else ``limit``;
    0: ``limit`` (every core numba may use); N > 0: ``min(N, limit)``. At least 1."""
    limit = max(1, int(limit))
    budget = int(budget)
    if budget < 0:
        return 1 if int(pixels) <= ONE_THREAD_MAX_PIXELS else limit
    return limit if budget == 0 else min(budget, limit)


def thread_count() -> int:
    """Threads the kernels may use (numba's current setting, at least 1)."""
    return max(1, int(numba.get_num_threads()))


def _executor(workers: int) -> ThreadPoolExecutor:
    """The shared pool with exactly ``workers`` threads (one per size, kept for reuse)."""
    with _pools_lock:
        pool = _pools.get(workers)
        if pool is None:
            pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="elas")
            _pools[workers] = pool
        return pool


def row_bands(n_rows: int, n_bands: int) -> list[tuple[int, int]]:
    """Split ``range(n_rows)`` into at most ``n_bands`` contiguous ``(start, stop)`` bands."""
    n_bands = max(1, min(n_bands, n_rows))
    edges = [round(i * n_rows / n_bands) for i in range(n_bands + 1)]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def run_row_bands(*jobs) -> None:
    """Run row kernels; each job is ``(kernel, n_rows, args)`` and calls
    ``kernel(*args, start, stop)`` over bands covering ``range(n_rows)``.

    All bands of all jobs go to the pool together (so the left and the right image
    share the threads); with one thread they run in order in the caller.
    """
    threads = thread_count()
    if threads == 1 or getattr(_local, "in_pool", False):
        # (inside a task of the pool, e.g. one side's post-processing: its bands run here,
        # waiting for the pool from one of its own threads could deadlock)
        for kernel, n_rows, args in jobs:
            kernel(*args, 0, n_rows)
        return
    pool = _executor(threads)
    futures = []
    for kernel, n_rows, args in jobs:
        for a, b in row_bands(n_rows, threads * BANDS_PER_THREAD):
            futures.append(pool.submit(kernel, *args, a, b))  # type: ignore[call-arg]  # (mypy: *args)
    for f in futures:
        f.result()


def _as_pool_task(task):
    """Run ``task()`` in a pool thread, marked as such for :func:`run_row_bands`."""
    _local.in_pool = True
    try:
        return task()
    finally:
        _local.in_pool = False


def run_tasks(*tasks):
    """Run zero-argument callables concurrently (in order when single-threaded);
    returns their results in order. Row bands started inside a task run in that task's
    thread (:func:`run_row_bands`)."""
    if thread_count() == 1 or len(tasks) < 2:
        return [t() for t in tasks]
    pool = _executor(thread_count())
    futures = [pool.submit(_as_pool_task, t) for t in tasks]
    return [f.result() for f in futures]
