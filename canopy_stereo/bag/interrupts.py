"""Work that a Ctrl-C (or SIGTERM/SIGHUP turned into a KeyboardInterrupt) cannot cut short.

The writer creates, appends to and closes its files through these helpers, so an
interrupt landing anywhere leaves a consistent file; the interrupt is raised again once
the work is done. (Raw locks and ``_thread``: the threading module's waits are not safe
against interrupts.)
"""
from __future__ import annotations

import _thread


def _run_into(fn, args, done, box) -> None:
    try:
        box.append((True, fn(*args)))
    except BaseException as exc:  # noqa: BLE001 - handed to the waiting caller
        box.append((False, exc))
    finally:
        done.release()


def _wait_done(done, box):
    """Wait (a KeyboardInterrupt meanwhile is held back) for a job; its result or exception."""
    interrupted = False
    while not box:  # (the job fills box before it releases done; an interrupt may land anywhere)
        try:
            done.acquire(timeout=0.05)
        except KeyboardInterrupt:
            interrupted = True
    ok, value = box[0]
    if not ok:
        raise value
    if interrupted:
        raise KeyboardInterrupt
    return value


def _run_to_end(fn, *args):
    """Run ``fn(*args)`` in a helper thread and wait for it: a KeyboardInterrupt (Ctrl-C, or
    SIGTERM/SIGHUP turned into one) arriving meanwhile cannot cut it short; it is raised
    again once ``fn`` is done. Exceptions of ``fn`` are raised in the caller. (Raw locks
    and ``_thread``: the threading module's waits are not safe against interrupts.)"""
    done = _thread.allocate_lock()
    done.acquire()
    box: list = []
    try:
        _thread.start_new_thread(_run_into, (fn, args, done, box))
    except RuntimeError:  # no new threads at interpreter shutdown: run it here
        return fn(*args)
    return _wait_done(done, box)

