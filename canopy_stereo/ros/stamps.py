"""Stamps of incoming frames that make no sense: zero, repeated, or far from the receive time.

A camera driver stamps each frame with its capture time (``header.stamp``); pairing, latency and
every output's stamp come from it. :class:`StampCheck` judges each stamp of a stream against the
stream's recent stamps and the receive time (nanoseconds, the node clock) and says what to do:

* **zero** (``0 s 0 ns``: a driver that never sets the stamp): with ``zero_stamps: restamp``
  (the default) the frame is stamped with its receive time, so pairing, latency and the outputs'
  stamps stay meaningful (to within the transport delay, a few ms); with ``drop`` it is dropped.
  Either way it is a warning with its reason on ``/diagnostics``;
* **duplicate** (the same stamp as the stream's previous frame, on a stream whose stamps
  advance: a driver that repeats a stamp, or sends a frame twice): dropped as a duplicate, and
  not counted again as a frame lost upstream when the next stamp leaves a gap. A stream that
  only ever repeats one stamp is a looping one-frame source, not a duplicate (the pairers treat
  each repeat as a new pass);
* **far from the receive time** (``|stamp - receive time| > max_stamp_gap`` seconds, when that
  parameter is > 0): kept, and a warning naming the gap (a driver with its own clock, a lagging
  capture, or a bag played with its recorded stamps: off by default for that reason).
"""
from __future__ import annotations

from dataclasses import dataclass

#: Values of the ``zero_stamps`` parameter.
ZERO_STAMP_CHOICES = ("restamp", "drop")

@dataclass(frozen=True)
class StampVerdict:
    """What to do with one frame: ``stamp_ns`` to use (None: drop it), ``drop_reason`` when
    dropped, ``warnings`` to report (each a reason, without the stream's name)."""

    stamp_ns: int | None
    drop_reason: str = ""
    warnings: tuple[str, ...] = ()


class StampCheck:
    """Judge the stamps of ``n_streams`` streams (see the module docstring).

    Args:
        zero_stamps: ``"restamp"`` (use the receive time) or ``"drop"``.
        max_gap_s: largest ``|stamp - receive time|`` (s) before a warning; 0 = never.
    """

    def __init__(self, n_streams: int, *, zero_stamps: str = "restamp", max_gap_s: float = 0.0):
        if zero_stamps not in ZERO_STAMP_CHOICES:
            raise ValueError(f"zero_stamps must be one of {', '.join(ZERO_STAMP_CHOICES)}, got {zero_stamps!r}")
        self.zero_stamps = zero_stamps
        self.max_gap_ns = int(max(0.0, float(max_gap_s)) * 1e9)
        self._last: list[int | None] = [None] * n_streams
        self._advanced = [False] * n_streams  # the stream's stamps have changed at least once
        self.duplicates = [0] * n_streams  # since the stream's last accepted stamp

    def check(self, stream: int, stamp_ns: int, received_ns: int) -> StampVerdict:
        """The verdict on a frame of ``stream`` stamped ``stamp_ns`` received at ``received_ns``."""
        if stamp_ns == 0:
            if self.zero_stamps == "drop":
                return StampVerdict(None, "zero stamp (the driver does not stamp its frames; "
                                          "zero_stamps: drop)")
            stamp_ns = int(received_ns)
            return StampVerdict(self._accept(stream, stamp_ns),
                                warnings=("zero stamp: restamped with the receive time (the driver does "
                                          "not stamp its frames; zero_stamps: restamp)",))
        if stamp_ns == self._last[stream] and self._advanced[stream]:
            self.duplicates[stream] += 1
            return StampVerdict(None, "duplicate stamp (the same stamp as an earlier frame of this camera: "
                                      "the driver repeats stamps)")
        warnings = ()
        gap = int(stamp_ns) - int(received_ns)
        if self.max_gap_ns and abs(gap) > self.max_gap_ns:
            side = "behind" if gap < 0 else "ahead of"
            warnings = (f"stamp {abs(gap) / 1e9:.3f} s {side} the receive time (max_stamp_gap "
                        f"{self.max_gap_ns / 1e9:g} s)",)
        return StampVerdict(self._accept(stream, stamp_ns), warnings=warnings)

    def _accept(self, stream: int, stamp_ns: int) -> int:
        last = self._last[stream]
        if last is not None and last != stamp_ns:
            self._advanced[stream] = True
        self._last[stream] = int(stamp_ns)
        return int(stamp_ns)

    def take_duplicates(self, stream: int) -> int:
        """Duplicates of ``stream`` since the last call (frames a gap in its stamps should not
        count as lost upstream: the driver sent them, with a repeated stamp)."""
        n, self.duplicates[stream] = self.duplicates[stream], 0
        return n
