"""Run many bags on Dask distributed: an embedded LocalCluster or an existing cluster.

:func:`run_batch` sends one task per bag, :func:`~canopy_stereo.batch.work.run_bag_task`
with the bag's *path* (workers read the bag from shared storage; nothing large
goes through the scheduler: a task is a path and the options, a result is one
row of numbers). Without ``scheduler`` it starts a ``LocalCluster`` of
``workers`` processes (one thread each) on this machine; with
``scheduler="tcp://host:8786"`` it connects a ``Client`` to a running cluster
(``dask scheduler`` + ``dask worker``, or dask-jobqueue on SLURM/HTCondor).

Rows are written as the bags complete (:class:`~canopy_stereo.batch.table.ResultTable`),
so an interrupted batch loses only the bags in flight, and ``resume=True``
submits only the bags that have no row yet.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from canopy_stereo.batch.table import ResultTable
from canopy_stereo.batch.work import BatchOptions, run_bag_task
from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.progress import Progress

BAG_SUFFIX = ".mcap"
#: glibc settings of the LocalCluster's workers (as the ROS node processes' allocator tuning,
#: :func:`canopy_stereo.ros.context.tune_memory_allocator`): frame-sized buffers stay on the heap
#: instead of Dask's default of trimming the heap above 64 kB (a page fault storm per frame).
_MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": str(256 << 20), "MALLOC_TRIM_THRESHOLD_": str(1 << 30),
               "MALLOC_TOP_PAD_": str(256 << 20)}


@dataclass
class BatchSummary:
    """What a batch did: counts of inputs and outcomes, the outputs written, seconds."""

    inputs: int = 0
    already_done: int = 0
    submitted: int = 0
    succeeded: int = 0
    failed: int = 0
    skipped: int = 0
    interrupted: bool = False
    seconds: float = 0.0
    outputs: list = field(default_factory=list)

    def lines(self) -> list[str]:
        """Human-readable summary."""
        rate = self.succeeded / (self.seconds / 60.0) if self.seconds > 0 else 0.0
        out = [f"{self.inputs} bag(s): {self.already_done} already in the table, {self.submitted} processed "
               f"-> {self.succeeded} measured, {self.failed} failed, {self.skipped} not selected "
               f"({self.seconds:.1f} s, {rate:.1f} bags/min)"]
        if self.interrupted:
            out.append("interrupted: rerun with --resume to process the rest")
        out += [f"wrote {p}" for p in self.outputs]
        return out


def expand_inputs(inputs) -> list[str]:
    """Absolute paths of the bags named by ``inputs``: ``.mcap`` files as given, and
    every ``*.mcap`` below a folder (sorted; rosbag2 bag folders included). Order kept,
    duplicates dropped. Raises :class:`CanopyStereoError` for a path that does not exist
    or a folder without bags."""
    out: list[str] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(q for q in p.rglob(f"*{BAG_SUFFIX}") if q.is_file())
            if not found:
                raise CanopyStereoError(f"no {BAG_SUFFIX} bag in folder {p}")
            out += [os.path.abspath(q) for q in found]
        elif p.exists():
            out.append(os.path.abspath(p))
        else:
            raise CanopyStereoError(f"input not found: {p}")
    return list(dict.fromkeys(out))


class _workers_ignore_interrupts:
    """While the LocalCluster starts its processes, SIGINT is ignored: they inherit that,
    so a Ctrl-C at a terminal (sent to the whole process group) stops the batch here, in
    one line, instead of in every worker with a traceback each; SIGTERM from a job
    scheduler is handled the same way by the command."""

    def __enter__(self):
        import signal
        import threading

        self.previous = None
        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        return self

    def __exit__(self, *exc):
        import signal

        if self.previous is not None:
            signal.signal(signal.SIGINT, self.previous)
        return False


def _client(scheduler: str | None, workers: int):
    """``(client, cluster)``: connected to ``scheduler``, or to a new LocalCluster."""
    try:
        import dask
        from distributed import Client, LocalCluster
    except ImportError:
        raise CanopyStereoError("batch needs Dask distributed: pip install 'canopy_stereo[batch]' "
                                "(or 'dask[distributed]')") from None
    if scheduler:
        try:
            return Client(scheduler, timeout="20s"), None
        except (OSError, TimeoutError) as exc:
            raise CanopyStereoError(f"cannot connect to the Dask scheduler at {scheduler}: {exc}") from None
    if workers < 1:
        raise CanopyStereoError(f"--workers must be >= 1, got {workers}")
    import logging

    # one thread per worker process, and no hidden thread pools under it
    environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
    environ.update({"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"})
    environ.update(_MALLOC_ENV)
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}), _workers_ignore_interrupts():
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster), cluster


def run_batch(inputs, out, *, options: BatchOptions | None = None, workers: int = 1,
              scheduler: str | None = None, resume: bool = False, progress: bool | None = None,
              plots: bool = True) -> BatchSummary:
    """Process bags into ``out/plants.csv`` (+ Parquet, plots) and ``out/errors.csv``.

    Args:
        inputs: bag files and folders of bags (see :func:`expand_inputs`).
        out: output folder.
        options: how each bag is processed (:class:`~canopy_stereo.batch.work.BatchOptions`).
        workers: processes of the embedded LocalCluster (ignored with ``scheduler``).
        scheduler: address of a running Dask scheduler (``tcp://host:8786``), or None.
        resume: keep the rows already in ``out`` and process only the other bags;
            without it an existing ``out/plants.csv`` is an error.
        progress: status line on stderr (default: when stderr is a terminal).
        plots: draw per-plant trait plots (needs matplotlib; skipped without it).

    Returns a :class:`BatchSummary`. On KeyboardInterrupt the rows of the bags
    finished so far are on disk and the summary has ``interrupted=True``.

    The LocalCluster starts its workers with ``multiprocessing``'s *spawn*: a script
    that calls this must do so under ``if __name__ == "__main__":``.
    """
    options = options or BatchOptions()
    t0 = time.monotonic()
    out = Path(out)
    if not resume and ResultTable(out, resume=True, create=False).rows:
        raise CanopyStereoError(f"{out / 'plants.csv'} has rows: add --resume to continue that batch, "
                                "or choose another output folder")
    paths = expand_inputs(inputs)
    table = ResultTable(out, resume=resume, create=False)
    todo = [p for p in paths if p not in table.done]
    summary = BatchSummary(inputs=len(paths), already_done=len(paths) - len(todo))
    client = cluster = None
    if todo:
        client, cluster = _client(scheduler, workers)  # fails before anything is written
    table.write()
    bar = Progress(len(todo), "bags", force=progress, keep=True)
    if todo:
        try:
            _run(client, todo, options, table, summary, bar)
        except KeyboardInterrupt:
            summary.interrupted = True
        finally:
            bar.close()
            _close_quietly(client, cluster, interrupted=summary.interrupted)
    summary.outputs += [out / "plants.csv", out / "errors.csv"]
    pq = table.write_parquet()
    if pq is not None:
        summary.outputs.append(pq)
    if plots and table.rows:
        from canopy_stereo.batch.plots import plot_traits

        summary.outputs += plot_traits(table, out / "plots")
    summary.seconds = time.monotonic() - t0
    return summary


def _close_quietly(client, cluster, *, interrupted: bool) -> None:
    """Close the client and the LocalCluster; after an interruption without Dask's
    shutdown chatter (its loggers silenced, a second Ctrl-C during the close ignored)."""
    import logging
    import signal
    import threading

    previous = None
    if interrupted:
        for name in ("distributed", "tornado", "asyncio"):
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        if threading.current_thread() is threading.main_thread():
            previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        try:
            client.close(timeout=10)
        finally:
            if cluster is not None:
                cluster.close(timeout=10)
    except Exception:  # noqa: BLE001 - closing after an interruption: nothing left to save
        if not interrupted:
            raise
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _run(client, todo, options, table, summary, bar) -> None:
    import uuid

    from distributed import as_completed

    opts = client.scatter(options, broadcast=True) if options.rig is not None else options
    run = uuid.uuid4().hex[:8]  # keys unique to this run: several batches may share a cluster
    futures = {client.submit(run_bag_task, path, opts, key=f"canopy-bag-{run}-{i}", pure=False, retries=0): path
               for i, path in enumerate(todo)}
    summary.submitted = len(futures)
    for fut in as_completed(futures):
        path = futures.pop(fut)
        try:
            status, value = fut.result()
        except Exception as exc:  # noqa: BLE001 - a worker that died on this bag
            status, value = "error", f"worker failed: {type(exc).__name__}: {' '.join(str(exc).split())}"
        if status == "ok":
            table.add_rows(value)
            summary.succeeded += 1
        elif status == "skipped":
            summary.skipped += 1
        else:
            table.add_error(path, value)
            summary.failed += 1
            bar.note(f"failed: {value}" if str(path) in str(value) else f"failed: {path}: {value}")  # as it happens
        fut.release()
        bar.step(ok=status != "error")
