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
partner and the result does not depend on arrival order across the streams
(:func:`slop_for_rate` gives half a period).

Time that jumps backwards (a looping bag, a restarted driver, a bag replayed after
a live run): when a stream's stamp is older than that stream's previous stamp by
more than the pairing tolerance (``slop``; for exact pairing
:data:`EXACT_JUMP_TOLERANCE_S`), or repeats a stamp that was already paired (a
looping one-frame bag), both classes *reset*: the "older than the last pair" rule
starts afresh on the new time line and ``on_jump(TimeJump)`` is called once for the
jump (the other streams following it later are part of the same reset and are not
reported again). The approximate pairer drops what was queued from before the jump
(its two cameras jump together); the exact synchronizer lets the sets of the old
time line still complete with the messages in flight (its inputs arrive with a
stage's delay between them) and drops them once the new time line has produced a set.

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
    """A message that left a synchronizer without being paired.

    ``after_jump``: dropped because time jumped back (queued before the jump); the jump
    itself is reported once through ``on_jump``."""

    stream: int
    stamp_ns: int
    reason: str
    after_jump: bool = False


@dataclass(frozen=True)
class TimeJump:
    """Stamps of ``stream`` went back from ``from_ns`` to ``to_ns`` (a reset followed)."""

    stream: int
    from_ns: int
    to_ns: int
    dropped: int

    @property
    def back_s(self) -> float:
        """How far the stamps went back, seconds (>= 0)."""
        return (self.from_ns - self.to_ns) / 1e9


#: Exact pairing: a stream stepping back by more than this (s) has jumped; the messages
#: carry copies of one upstream stamp, so smaller steps can only be late deliveries.
EXACT_JUMP_TOLERANCE_S = 0.001


def slop_for_rate(fps: float) -> float:
    """Pairing tolerance for free-running cameras at ``fps`` frames/s: half a frame period (s).

    Any two frames of the two cameras are then at most one tolerance from their nearest
    partner, and no frame has two candidates."""
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    return 0.5 / float(fps)


class _JumpGuard:
    """Per-stream "stamps went back" detection shared by both synchronizers.

    ``check(stream, stamp, repeat_is_jump)`` returns ``"jump"`` (a new jump: reset and report),
    ``"follow"`` (this stream follows a jump another stream already reported: reset
    silently) or ``""`` (no jump)."""

    def __init__(self, n_streams: int, tolerance_ns: int):
        self.tolerance_ns = int(tolerance_ns)
        self.last: list = [None] * n_streams
        self.following: set = set()  # streams still on the time line before the last jump

    def check(self, stream: int, stamp: int, repeat_is_jump: bool = True) -> str:
        last = self.last[stream]
        jumped = last is not None and (stamp < last - self.tolerance_ns or (stamp == last and repeat_is_jump))
        self.last[stream] = stamp if last is None or jumped or stamp > last else last
        if not jumped:
            return ""
        if stream in self.following:
            self.following.discard(stream)
            return "follow"
        self.following = {i for i in range(len(self.last)) if i != stream and self.last[i] is not None}
        return "jump"

    def settled(self) -> None:
        """A pair/set completed: every stream is on the same time line."""
        self.following.clear()

    def set_tolerance(self, tolerance_ns: int) -> None:
        self.tolerance_ns = int(tolerance_ns)


class FramePeriodEstimator:
    """Frame period of a camera pair from the stamps it sends (median of recent intervals).

    ``observe(stream, stamp_ns)`` returns the current estimate in seconds, or None
    until ``min_intervals`` intervals between consecutive frames of a stream were
    seen. Intervals that are not positive or longer than ``max_interval_s`` (a time
    jump, a pause) are ignored.
    """

    def __init__(self, n_streams: int = 2, *, window: int = 15, min_intervals: int = 2,
                 max_interval_s: float = 2.0):
        self._last: list = [None] * n_streams
        self._intervals: list[int] = []
        self.window, self.min_intervals = int(window), int(min_intervals)
        self.max_interval_ns = int(max_interval_s * 1e9)
        self._lock = threading.Lock()

    def observe(self, stream: int, stamp_ns: int) -> float | None:
        with self._lock:
            last, self._last[stream] = self._last[stream], int(stamp_ns)
            if last is not None and 0 < stamp_ns - last <= self.max_interval_ns:
                self._intervals.append(int(stamp_ns) - last)
                del self._intervals[:-self.window]
            if len(self._intervals) < self.min_intervals:
                return None
            return sorted(self._intervals)[len(self._intervals) // 2] / 1e9


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
        slop_s: largest accepted stamp difference in seconds (0 = exact); also the
            tolerance beyond which stamps going back count as a time jump.
        queue_size: frames kept per stream while waiting for a partner (>= 1).
        on_jump: ``f(TimeJump)`` called (under the pairer's lock, keep it short) once
            per backwards time jump, after the reset.
    """

    def __init__(self, slop_s: float, queue_size: int = 5, *, on_jump=None):
        if slop_s < 0:
            raise ValueError(f"slop must be >= 0 s, got {slop_s}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.slop_ns = int(round(slop_s * 1e9))
        self.queue_size = int(queue_size)
        self.on_jump = on_jump
        self.jumps = 0
        self._queues = (_Queue(), _Queue())
        self._guard = _JumpGuard(2, self.slop_ns)
        self._lock = threading.Lock()

    def set_slop(self, slop_s: float) -> None:
        """Change the pairing tolerance (s) from the next frame on."""
        if slop_s < 0:
            raise ValueError(f"slop must be >= 0 s, got {slop_s}")
        with self._lock:
            self.slop_ns = int(round(slop_s * 1e9))
            self._guard.set_tolerance(self.slop_ns)

    def _reset(self, stream: int, stamp_ns: int, previous: int, kind: str) -> list[Dropped]:
        """Forget the time line before ``stream`` jumped from ``previous`` to ``stamp_ns``:
        the stream's own queue and, when it jumps first, the other stream's frames later
        than the new stamp (a stream that follows finds the other's queue on the new line)."""
        dropped = []
        for i, q in enumerate(self._queues):
            if i != stream and kind != "jump":
                keep = [True] * len(q.stamps)
            else:
                keep = [i != stream and s <= stamp_ns + self.slop_ns for s in q.stamps]
            dropped += [Dropped(i, s, "time jumped back: queued before the jump", after_jump=True)
                        for s, k in zip(q.stamps, keep) if not k]
            q.stamps[:] = [s for s, k in zip(q.stamps, keep) if k]
            q.items[:] = [it for it, k in zip(q.items, keep) if k]
            q.last_paired = None
        if kind == "jump":
            self.jumps += 1
            if self.on_jump is not None:
                self.on_jump(TimeJump(stream, previous, stamp_ns, len(dropped)))
        return dropped

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
            previous = self._guard.last[stream]
            kind = self._guard.check(stream, stamp_ns, repeat_is_jump=stamp_ns not in mine.stamps)
            if kind:
                dropped += self._reset(stream, stamp_ns, previous, kind)
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
            self._guard.settled()
            if stream == 0:
                return Pair((stamp_ns, other_stamp), (item, other_item)), dropped
            return Pair((other_stamp, stamp_ns), (other_item, item)), dropped

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
            self._guard = _JumpGuard(2, self.slop_ns)
            return dropped


class ExactTimeSynchronizer:
    """Group messages of ``n_streams`` streams that carry the same stamp.

    Time lines: a backwards jump opens a new *epoch*; a stream belongs to the new epoch
    from its own first message after the jump (streams follow at their own pace: the
    slow stream's messages from before the jump still complete their sets). A message
    whose stamp a pending set of another epoch lacks completes that set, the stream joining
    a newer epoch so: a stream that never saw the jump (it started after it, or skipped from
    one pass of a looping source into the next without stepping back, and then gets one
    frame again and again) would otherwise wait in its own epoch forever. A set
    completed in the newest epoch drops every set left from older epochs.

    Args:
        n_streams: number of inputs (>= 1).
        queue_size: incomplete stamps kept while waiting (>= 1); the oldest is dropped first.
        jump_tolerance_s: a stream stepping back further than this (s) is a time jump
            (default :data:`EXACT_JUMP_TOLERANCE_S`); smaller steps are late messages.
        on_jump: ``f(TimeJump)`` called once per backwards time jump (or a repeated
            stamp of a set already emitted).
    """

    def __init__(self, n_streams: int, queue_size: int = 5, *, jump_tolerance_s: float | None = None,
                 on_jump=None):
        if n_streams < 1:
            raise ValueError(f"n_streams must be >= 1, got {n_streams}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.n_streams = int(n_streams)
        self.queue_size = int(queue_size)
        self._pending: dict[tuple[int, int], list] = {}  # (epoch, stamp) -> slots, in creation order
        self._last_emitted: dict[int, int] = {}           # epoch -> stamp of its last emitted set
        self._epoch = 0
        self._stream_epoch = [0] * self.n_streams
        self.on_jump = on_jump
        self.jumps = 0
        tol = EXACT_JUMP_TOLERANCE_S if jump_tolerance_s is None else float(jump_tolerance_s)
        if tol < 0:
            raise ValueError(f"jump tolerance must be >= 0 s, got {tol}")
        self._guard = _JumpGuard(self.n_streams, int(round(tol * 1e9)))
        self._lock = threading.Lock()

    def push(self, stream: int, stamp_ns: int, item) -> tuple[list | None, list[Dropped]]:
        """Add ``item``; returns ``(items, dropped)`` where ``items`` (one per stream,
        in stream order) is the set completed by this message, or None."""
        if not 0 <= stream < self.n_streams:
            raise ValueError(f"stream must be in [0, {self.n_streams}), got {stream}")
        stamp_ns = int(stamp_ns)
        with self._lock:
            dropped: list[Dropped] = []
            previous = self._guard.last[stream]
            queued = self._pending.get((self._stream_epoch[stream], stamp_ns))
            kind = self._guard.check(stream, stamp_ns, repeat_is_jump=queued is None or queued[stream] is None)
            if kind == "jump":
                self._epoch += 1
                self.jumps += 1
                if self.on_jump is not None:
                    stale = sum(1 for (e, _), slots in self._pending.items() if e < self._epoch
                                and slots[stream] is not None)
                    self.on_jump(TimeJump(stream, previous, stamp_ns, stale))
            if kind:
                self._stream_epoch[stream] = self._epoch
                # this stream's messages from before the jump can no longer complete a set
                for key in [k for k, slots in self._pending.items()
                            if k[0] < self._epoch and slots[stream] is None]:
                    dropped += self._drop_set(key, "time jumped back: queued before the jump", after_jump=True)
            epoch = self._stream_epoch[stream]
            waiting = self._set_waiting_for(stream, stamp_ns)
            if waiting is None:
                last = self._last_emitted.get(epoch)
                if last is not None and stamp_ns <= last:
                    return None, dropped + [Dropped(stream, stamp_ns, "older than the last emitted set")]
                waiting = (epoch, stamp_ns)
            elif waiting[0] > epoch:  # the others' time line, reached without a step back: joined
                self._stream_epoch[stream] = waiting[0]
                if waiting[0] == self._epoch:
                    self._guard.following.discard(stream)
            epoch, key = waiting[0], waiting
            slots = self._pending.setdefault(key, [None] * self.n_streams)
            if slots[stream] is not None:
                dropped.append(Dropped(stream, stamp_ns, "duplicate stamp (replaced)"))
            slots[stream] = (item,)
            if all(s is not None for s in slots):
                del self._pending[key]
                for old in [k for k in self._pending if k[0] < epoch or (k[0] == epoch and k[1] < stamp_ns)]:
                    reason = ("time jumped back: queued before the jump" if old[0] < epoch
                              else "incomplete when a later set completed")
                    dropped += self._drop_set(old, reason, after_jump=old[0] < epoch)
                self._last_emitted[epoch] = stamp_ns
                for e in [e for e in self._last_emitted if e < epoch]:
                    del self._last_emitted[e]
                if epoch == self._epoch:
                    self._guard.settled()
                return [s[0] for s in slots], dropped
            while len(self._pending) > self.queue_size:
                dropped += self._drop_set(next(iter(self._pending)), f"incomplete (queue of {self.queue_size} full)")
            return None, dropped

    def _set_waiting_for(self, stream: int, stamp_ns: int) -> tuple[int, int] | None:
        """The key of the pending set stamped ``stamp_ns`` that lacks ``stream``'s message: the
        one of the stream's own time line, else the newest (None: no such set). A stream whose
        stamps step forward across a jump (a looping source whose frames it partly skipped) never
        sees the jump; the others' set of its stamp is the one it completes."""
        keys = [k for k, slots in self._pending.items() if k[1] == stamp_ns and slots[stream] is None]
        own = (self._stream_epoch[stream], stamp_ns)
        return own if own in keys else max(keys, default=None)

    def _drop_set(self, key: tuple[int, int], reason: str, *, after_jump: bool = False) -> list[Dropped]:
        slots = self._pending.pop(key)
        return [Dropped(i, key[1], reason, after_jump) for i, s in enumerate(slots) if s is not None]

    def pending(self) -> int:
        """Number of incomplete stamps waiting."""
        with self._lock:
            return len(self._pending)
