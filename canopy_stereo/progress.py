"""The package's one progress reporter: how far a long command is, on stderr.

:class:`Progress` counts ``N`` steps and writes to a stream (stderr by default), so stdout
keeps only a command's results. Two styles, one counter:

* a status line (the default): ``label k/N (elapsed s, about T s left)[, f failed]: what``,
  rewritten in place on a terminal and silent when the stream is not one (logs, CI) unless
  ``force``; ``keep=True`` leaves the last line standing at :meth:`Progress.close` (a batch's
  final count), else it is wiped;
* a log (``lines=True``): one line per step, ``elapsed s  [k/N] what``, and per
  :meth:`Progress.detail`, for runs whose log is read afterwards (``canopy-stereo paper``);
  ``force=False`` silences it.

Used by the CLI commands, ``canopy-stereo batch`` (:mod:`canopy_stereo.batch.engine`) and
the paper run (:mod:`canopy_stereo.pipeline.paper`).
"""
from __future__ import annotations

import os
import sys
import time


class Progress:
    """Progress of ``total`` steps (see the module docstring).

    Use as ``with Progress(n, "views") as p: ... p.step(name)``.

    Args:
        total: number of steps.
        label: what is counted (``"views"``, ``"frames shown"``); the status line starts with it.
        stream: where to write (default ``sys.stderr``).
        force: write (True) or not (False) whatever the stream is; default: a status line only
            on a terminal (not ``TERM=dumb``), a log always.
        lines: a log of lines instead of a status line.
        keep: leave the last status line on the terminal at :meth:`close` (with a newline).
    """

    def __init__(self, total: int, label: str = "", *, stream=None, force: bool | None = None,
                 lines: bool = False, keep: bool = False):
        self.total = int(total)
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.lines = bool(lines)
        self.keep = bool(keep)
        if force is None:
            tty = hasattr(self.stream, "isatty") and self.stream.isatty() and os.environ.get("TERM") != "dumb"
            force = True if self.lines else tty
        self.enabled = bool(force)
        self.done = self.failed = 0
        self.t0 = time.perf_counter()
        self._width = 0

    def elapsed(self) -> float:
        """Seconds since the reporter was made."""
        return time.perf_counter() - self.t0

    def step(self, what: str = "", n: int = 1, *, ok: bool = True) -> None:
        """``n`` more steps done (a log: step ``done`` starts); ``what``: its name, shown;
        ``ok=False`` counts them as failed (shown as ``f failed``)."""
        self.done += n
        self.failed += 0 if ok else n
        if not self.enabled:
            return
        if self.lines:
            self._line(f"[{self.done}/{self.total}] {what}")
            return
        elapsed = self.elapsed()
        left = ""
        if 0 < self.done < self.total:
            left = f", about {elapsed / self.done * (self.total - self.done):.0f} s left"
        failed = f", {self.failed} failed" if self.failed or not ok or self.keep else ""
        text = (f"{self.label} {self.done}/{self.total} ({elapsed:.0f} s{left}){failed}"
                + (f": {what}" if what else "")).lstrip()
        pad = max(0, self._width - len(text))
        self._width = len(text)
        self.stream.write("\r" + text + " " * pad)
        self.stream.flush()

    def detail(self, message: str) -> None:
        """A line within the current step (a log only)."""
        if self.enabled and self.lines:
            self._line(f"      {message}")

    def _line(self, text: str) -> None:
        print(f"{self.elapsed():7.1f} s  {text}", file=self.stream, flush=True)

    def note(self, line: str) -> None:
        """Print ``line`` on the stream now, whether the reporter shows progress or not (a
        failure as it happens): over a wiped status line on a terminal, which the next step redraws."""
        if self.enabled and self._width and not self.lines:
            self.stream.write("\r" + " " * self._width + "\r")
            self._width = 0
        print(line, file=self.stream, flush=True)

    def close(self) -> None:
        """End the status line: kept with a newline (``keep``), else wiped."""
        if self.enabled and self._width:
            self.stream.write("\n" if self.keep else "\r" + " " * self._width + "\r")
            self.stream.flush()
            self._width = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
