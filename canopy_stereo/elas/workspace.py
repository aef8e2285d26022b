"""Scratch arrays that ELAS reuses from frame to frame, one set per thread.

Fresh large arrays cost page faults: at 640x480 an ELAS run needs about 25 MB of
intermediate maps (descriptors, triangle maps, raw disparities, filter scratch),
and when they come from new pages every frame the kernel's page-fault handling
took ~6 ms CPU per frame (~20 % of the run; measured with ``getrusage`` minor
faults, 5400 per frame). :func:`elas_run <canopy_stereo.elas.core.elas_run>`
takes its intermediates from the calling thread's :class:`Workspace` instead; the
arrays it returns are always fresh (never workspace memory).
"""
from __future__ import annotations

import threading

import numpy as np


class Workspace:
    """Named scratch arrays, kept between calls (contents are not preserved).

    :meth:`array` returns the array stored under a name, re-allocating it when the
    shape or dtype changed. :meth:`scoped` gives a view whose names carry a prefix,
    so that two concurrent tasks of one run (left and right image) never share an
    array. Not for sharing between threads: use :func:`thread_workspace`.
    """

    def __init__(self, _store: dict | None = None, _prefix: str = ""):
        self._store = {} if _store is None else _store
        self._prefix = _prefix

    def array(self, name: str, shape: tuple[int, ...], dtype) -> np.ndarray:
        """C-contiguous array ``shape``/``dtype`` stored under ``name`` (uninitialised)."""
        key = self._prefix + name
        shape = tuple(int(s) for s in shape)
        dtype = np.dtype(dtype)
        arr = self._store.get(key)
        if arr is None or arr.shape != shape or arr.dtype != dtype:
            arr = np.empty(shape, dtype)
            self._store[key] = arr
        return arr

    def scoped(self, prefix: str) -> Workspace:
        """The same store, with ``prefix`` before every name."""
        return Workspace(self._store, self._prefix + prefix + "/")

    def arrays(self) -> list[np.ndarray]:
        """Every array of the store (all prefixes)."""
        return list(self._store.values())

    def nbytes(self) -> int:
        """Bytes held by all arrays of the store."""
        return sum(a.nbytes for a in self._store.values())

    def clear(self) -> None:
        """Drop every array of the store (memory is released when unreferenced)."""
        self._store.clear()


_local = threading.local()


def thread_workspace() -> Workspace:
    """The calling thread's workspace (created on first use)."""
    ws = getattr(_local, "workspace", None)
    if ws is None:
        ws = _local.workspace = Workspace()
    return ws
