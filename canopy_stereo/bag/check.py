"""What a check of a bag found: each damaged place, and the whole file's report."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple


class BagDamage(NamedTuple):
    """One damaged place of a bag.

    Attributes:
        offset: byte offset of the damaged record (or of the first byte that does
            not parse) in the file.
        length: bytes skipped there (0 when nothing had to be skipped).
        problem: what is wrong, one line.
        messages_lost: messages that could not be read because of it (None: unknown,
            e.g. a cut inside a chunk whose index never got written).
    """

    offset: int
    length: int
    problem: str
    messages_lost: int | None

    def describe(self, path) -> str:
        lost = ("" if self.messages_lost == 0 else
                f" ({'an unknown number of' if self.messages_lost is None else self.messages_lost}"
                f" message{'' if self.messages_lost == 1 else 's'} lost)")
        return f"{path}: offset {self.offset}: {self.problem}{lost}"



@dataclass
class BagCheck:
    """The outcome of :meth:`BagReader.verify`: what a full read of every chunk found.

    Attributes:
        path: the file.
        complete: the file ends with a valid summary and footer.
        chunks, chunks_damaged: chunks found, and how many of them are damaged.
        messages_recovered: topic -> messages that read intact.
        messages_lost: messages known lost; ``lost_unknown``: some losses cannot be counted.
        damage: every damaged place (:class:`BagDamage`).
        chunks_unverifiable: chunks stored without a CRC (their messages cannot be checked).
        data_crc: ``"ok"``, ``"mismatch"`` or ``"absent"`` (the writer stored none).
        summary: ``"ok"``, ``"damaged"`` or ``"absent"``.
    """

    path: Path
    complete: bool
    chunks: int
    chunks_damaged: int
    messages_recovered: dict
    messages_lost: int
    lost_unknown: bool
    damage: list
    data_crc: str
    summary: str
    chunks_unverifiable: int = 0

    @property
    def ok(self) -> bool:
        """No damage of any kind and a complete file."""
        return self.complete and not self.damage

    def lines(self) -> list[str]:
        """Human-readable report (integrity, topics, counts, what is recoverable)."""
        total = sum(self.messages_recovered.values())
        other = [d for d in self.damage if "cut short" not in d.problem]
        state = ("OK" if self.ok else "DAMAGED" if other else
                 "TRUNCATED (cut short or never closed: no summary/footer)")
        out = [f"bag: {self.path}", f"integrity: {state}",
               f"summary: {self.summary}; data-section CRC: {self.data_crc}; "
               f"chunks: {self.chunks} ({self.chunks_damaged} damaged"
               + (f", {self.chunks_unverifiable} without CRC: not verifiable" if self.chunks_unverifiable
                  else "") + ")"]
        for d in self.damage:
            out.append("  damage: " + d.describe(self.path).split(": ", 1)[1])
        lost = (f"{self.messages_lost} counted + an unknown number in unreadable parts"
                if self.lost_unknown else str(self.messages_lost))
        out.append(f"messages readable intact: {total}; lost: {lost}")
        for topic, n in sorted(self.messages_recovered.items()):
            out.append(f"  {topic}  {n} msgs")
        if not self.ok:
            out.append("recoverable: every message listed above (canopy-stereo bag repair FILE -o OUT)"
                       if total else "recoverable: nothing")
        return out
