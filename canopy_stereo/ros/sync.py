"""Pairing of message streams by time stamp (a small ``message_filters``).

Two webcams are never exactly in step, so the rectify node pairs left and right
frames by *approximate* time; the downstream nodes receive messages that share
one stamp and pair them *exactly*. Both are pure Python (no ROS imports) and
thread-safe; stamps are integer nanoseconds.

:class:`ApproximateTimePairer` (two streams, per-stream arrival in stamp order):

* an arriving frame is paired at once with the queued frame of the other stream
  whose stamp is nearest, if that is within ``slop``;
* a pair is final: frames of either stream older than a pair can no longer be
  paired (pairs never cross) and are dropped with a reason;
* frames without a partner wait, at most ``queue_size`` per stream (the oldest
  is dropped first); frames that arrive older than the last pair of their
  stream, or with a stamp already queued, are dropped.

With ``slop`` below half the frame period every frame has at most one candidate
partner and the result does not depend on arrival order across the streams.

:class:`ExactTimeSynchronizer` (N streams): emits the set of messages once every
stream has delivered one with the same stamp; older incomplete sets are
dropped when a newer set completes, or when more than ``queue_size`` are pending.
"""
from __future__ import annotations

import bisect
import threading
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Dropped:
    """A message that left a synchronizer without being paired."""

    stream: int
    stamp_ns: int
    reason: str


@dataclass(frozen=True)
class Pair:
    """Two messages paired by time: ``items[i]`` came from stream ``i``."""

    stamps_ns: tuple[int, int]
    items: tuple[Any, Any]

    @property
    def stamp_ns(self) -> int:
        """Stamp of the pair: the later of the two stamps (ns)."""
        return max(self.stamps_ns)

    @property
    def skew_ns(self) -> int:
        """Absolute stamp difference of the two messages (ns)."""
        return abs(self.stamps_ns[0] - self.stamps_ns[1])


@dataclass
class _Queue:
    stamps: list = field(default_factory=list)
    items: list = field(default_factory=list)
    last_paired: int | None = None

    def insert(self, stamp, item):
        i = bisect.bisect_left(self.stamps, stamp)
        self.stamps.insert(i, stamp)
        self.items.insert(i, item)

    def pop(self, i):
        return self.stamps.pop(i), self.items.pop(i)


class ApproximateTimePairer:
    """Pair two streams by nearest stamp within ``slop`` (see module docstring).

    Args:
        slop_s: largest accepted stamp difference in seconds (0 = exact).
        queue_size: frames kept per stream while waiting for a partner (>= 1).
    """

    def __init__(self, slop_s: float, queue_size: int = 5):
        if slop_s < 0:
            raise ValueError(f"slop must be >= 0 s, got {slop_s}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.slop_ns = int(round(slop_s * 1e9))
        self.queue_size = int(queue_size)
        self._queues = (_Queue(), _Queue())
        self._lock = threading.Lock()

    def push(self, stream: int, stamp_ns: int, item) -> tuple[Pair | None, list[Dropped]]:
        """Add ``item`` stamped ``stamp_ns`` to ``stream`` (0 or 1).

        Returns ``(pair, dropped)``: the pair completed by this message (or None)
        and the messages dropped while handling it.
        """
        if stream not in (0, 1):
            raise ValueError(f"stream must be 0 or 1, got {stream}")
        stamp_ns = int(stamp_ns)
        with self._lock:
            mine, other = self._queues[stream], self._queues[1 - stream]
            dropped: list[Dropped] = []
            if mine.last_paired is not None and stamp_ns <= mine.last_paired:
                return None, [Dropped(stream, stamp_ns, "older than the last pair of its stream")]
            if stamp_ns in mine.stamps:
                return None, [Dropped(stream, stamp_ns, "duplicate stamp")]
            j = self._nearest(other.stamps, stamp_ns)
            if j is None:
                mine.insert(stamp_ns, item)
                while len(mine.stamps) > self.queue_size:
                    s, _ = mine.pop(0)
                    dropped.append(Dropped(stream, s, f"no partner within {self.slop_ns / 1e9:g} s "
                                                      f"(queue of {self.queue_size} full)"))
                return None, dropped
            other_stamp, other_item = other.pop(j)
            for q, s_idx, limit in ((mine, stream, stamp_ns), (other, 1 - stream, other_stamp)):
                while q.stamps and q.stamps[0] < limit:
                    s, _ = q.pop(0)
                    dropped.append(Dropped(s_idx, s, "unpaired: no partner frame before a later pair"))
            mine.last_paired, other.last_paired = stamp_ns, other_stamp
            stamps = [0, 0]
            items = [None, None]
            stamps[stream], items[stream] = stamp_ns, item
            stamps[1 - stream], items[1 - stream] = other_stamp, other_item
            return Pair(tuple(stamps), tuple(items)), dropped

    def _nearest(self, stamps: list, t: int) -> int | None:
        if not stamps:
            return None
        i = bisect.bisect_left(stamps, t)
        best = None
        for k in (i - 1, i):
            if 0 <= k < len(stamps):
                gap = abs(stamps[k] - t)
                if gap <= self.slop_ns and (best is None or gap < abs(stamps[best] - t)):
                    best = k
        return best

    def pending(self) -> tuple[int, int]:
        """Number of frames waiting in each stream."""
        with self._lock:
            return len(self._queues[0].stamps), len(self._queues[1].stamps)

    def clear(self) -> list[Dropped]:
        """Forget everything queued (e.g. after a clock jump); returns what was dropped."""
        with self._lock:
            dropped = [Dropped(i, s, "cleared") for i, q in enumerate(self._queues) for s in q.stamps]
            self._queues = (_Queue(), _Queue())
            return dropped


class ExactTimeSynchronizer:
    """Group messages of ``n_streams`` streams that carry the same stamp.

    Args:
        n_streams: number of inputs (>= 1).
        queue_size: incomplete stamps kept while waiting (>= 1).
    """

    def __init__(self, n_streams: int, queue_size: int = 5):
        if n_streams < 1:
            raise ValueError(f"n_streams must be >= 1, got {n_streams}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.n_streams = int(n_streams)
        self.queue_size = int(queue_size)
        self._pending: dict[int, list] = {}
        self._last_emitted: int | None = None
        self._lock = threading.Lock()

    def push(self, stream: int, stamp_ns: int, item) -> tuple[list | None, list[Dropped]]:
        """Add ``item``; returns ``(items, dropped)`` where ``items`` (one per stream,
        in stream order) is the set completed by this message, or None."""
        if not 0 <= stream < self.n_streams:
            raise ValueError(f"stream must be in [0, {self.n_streams}), got {stream}")
        stamp_ns = int(stamp_ns)
        with self._lock:
            dropped: list[Dropped] = []
            if self._last_emitted is not None and stamp_ns <= self._last_emitted:
                return None, [Dropped(stream, stamp_ns, "older than the last emitted set")]
            slots = self._pending.setdefault(stamp_ns, [None] * self.n_streams)
            if slots[stream] is not None:
                dropped.append(Dropped(stream, stamp_ns, "duplicate stamp (replaced)"))
            slots[stream] = (item,)
            if all(s is not None for s in slots):
                del self._pending[stamp_ns]
                for old in sorted(s for s in self._pending if s < stamp_ns):
                    dropped += self._drop_set(old, "incomplete when a later set completed")
                self._last_emitted = stamp_ns
                return [s[0] for s in slots], dropped
            while len(self._pending) > self.queue_size:
                dropped += self._drop_set(min(self._pending), f"incomplete (queue of {self.queue_size} full)")
            return None, dropped

    def _drop_set(self, stamp: int, reason: str) -> list[Dropped]:
        slots = self._pending.pop(stamp)
        return [Dropped(i, stamp, reason) for i, s in enumerate(slots) if s is not None]

    def pending(self) -> int:
        """Number of incomplete stamps waiting."""
        with self._lock:
            return len(self._pending)
