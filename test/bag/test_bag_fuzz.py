"""Damaged bags: the reader never returns altered data and never lets a foreign exception out.

At least 200 damaged copies of the bundled bags (zstd, and an lz4 copy written here): byte
flips in chunk payloads, chunk headers, message indexes, the summary and the footer;
truncations; zeroed ranges; several flips at once. For each: every message returned equals
the original one (topic, times, bytes), every error is a BagError, and every chunk whose
bytes were not touched has all its messages returned (compared with the original file).
The damage is chosen by fixed seeds, so every run checks the same files.
"""
from __future__ import annotations

import struct
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("mcap")

pytestmark = pytest.mark.slow  # hundreds of damaged bags

from canopy_stereo.bag import BagError, BagReader, BagWriter  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag  # noqa: E402

MAGIC = b"\x89MCAP0\r\n"


def layout(data: bytes) -> dict:
    """Byte ranges of the file's records, found independently of the reader under test."""
    footer_at = len(data) - 8 - 29
    _, _, summary_start, _, _ = struct.unpack_from("<BQQQI", data, footer_at)
    chunks, others = [], []
    p = 8
    while p < summary_start:
        op, length = struct.unpack_from("<BQ", data, p)
        rng = (p, p + 9 + length)
        if op == 0x06:
            chunks.append(rng)
        else:
            others.append((op, rng))
        p += 9 + length
    return {"chunks": chunks, "others": others, "summary": (summary_start, footer_at),
            "footer": (footer_at, len(data))}


def chunk_messages(data: bytes, rng) -> list:
    """(topic, log, publish, bytes) of the messages in one chunk record of an intact file."""
    import io

    from mcap.exceptions import EndOfFile
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    # the magic and the chunk alone, read with mcap's own reader (which ends at EOF)
    buf = io.BytesIO(MAGIC + data[rng[0]:rng[1]])
    out = []
    try:
        for rec in StreamReader(buf, skip_magic=False).records:
            if isinstance(rec, Message):
                out.append((rec.channel_id, rec.log_time, rec.publish_time, bytes(rec.data)))
    except EndOfFile:
        pass
    return out


def build_sources(tmp: Path) -> dict:
    """name -> (bytes, layout, {(topic, log, pub): data}, {chunk range: [keys]}) for the bundled
    bags (zstd) and an lz4 copy of the croton written into ``tmp``."""
    from mcap.reader import make_reader

    lz4_path = Path(tmp) / "croton_lz4.mcap"
    with BagWriter(lz4_path, compression="lz4", chunk_size=400_000, flush_period_s=0) as w:
        for m in BagReader(bundled_bag("croton")).messages():
            w.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=m.type_name)
    out = {}
    for name, path in (("croton", bundled_bag("croton")), ("plants", bundled_bag("plants")),
                       ("croton_lz4", lz4_path)):
        data = Path(path).read_bytes()
        with open(path, "rb") as f:
            reader = make_reader(f)
            topics = {c.id: c.topic for c in reader.get_summary().channels.values()}
            original = {(c.topic, m.log_time, m.publish_time): bytes(m.data)
                        for _, c, m in reader.iter_messages()}
        lay = layout(data)
        per_chunk = {rng: [(topics[cid], lt, pt) for cid, lt, pt, _ in chunk_messages(data, rng)]
                     for rng in lay["chunks"]}
        assert sum(len(v) for v in per_chunk.values()) == len(original)
        out[name] = (data, lay, original, per_chunk)
    return out


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    return build_sources(tmp_path_factory.mktemp("fuzz"))


def variants(name, data: bytes, lay: dict, n: int, seed: int):
    """``n`` damaged copies: (label, bytes, damaged byte ranges)."""
    rng = np.random.default_rng(seed)
    kinds = ["payload", "chunk_header", "summary", "footer", "truncate", "zero", "index", "multi"]
    for i in range(n):
        kind = kinds[i % len(kinds)]
        buf = bytearray(data)
        ranges = []

        def flip(pos, buf=buf, ranges=ranges):
            buf[pos] ^= int(rng.integers(1, 256))
            ranges.append((pos, pos + 1))

        if kind == "payload":
            a, b = lay["chunks"][rng.integers(len(lay["chunks"]))]
            flip(int(rng.integers(a + 60, b)))
        elif kind == "chunk_header":
            a, _ = lay["chunks"][rng.integers(len(lay["chunks"]))]
            flip(int(rng.integers(a, a + 57)))
        elif kind == "summary":
            a, b = lay["summary"]
            flip(int(rng.integers(a, b)))
        elif kind == "footer":
            a, b = lay["footer"]
            flip(int(rng.integers(a, b)))
        elif kind == "truncate":
            cut = int(rng.integers(9, len(data)))
            del buf[cut:]
            ranges.append((cut, len(data)))
        elif kind == "zero":
            start = int(rng.integers(8, len(data) - 1))
            length = int(rng.integers(1, 70_000))
            end = min(len(data), start + length)
            buf[start:end] = bytes(end - start)
            if data[start:end] != bytes(buf[start:end]):
                ranges.append((start, end))
        elif kind == "index":
            others = [r for op, r in lay["others"] if op != 0x01] or [lay["summary"]]
            a, b = others[rng.integers(len(others))]
            flip(int(rng.integers(a, b)))
        else:
            for _ in range(int(rng.integers(2, 6))):
                flip(int(rng.integers(8, len(data))))
        yield f"{name}#{i}:{kind}", bytes(buf), ranges


COUNTS = {"croton": 80, "plants": 64, "croton_lz4": 80}


def run_fuzz(sources: dict, counts: dict, workdir: Path) -> tuple[Counter, list]:
    """Read every damaged variant; returns the tally and the list of property violations."""
    tally = Counter()
    failures = []
    path = Path(workdir) / "variant.mcap"
    for seed, (name, n) in enumerate(counts.items()):
        data, lay, original, per_chunk = sources[name]
        for label, damaged, ranges in variants(name, data, lay, n, 1000 + seed):
            tally["variants"] += 1
            tally[f"variants_{label.split(':')[1]}"] += 1
            path.write_bytes(damaged)
            got = []
            try:
                reader = BagReader(path)
                got = [(m.topic, m.log_time_ns, m.publish_time_ns, m.data) for m in reader.messages()]
                check = reader.verify()
            except BagError as exc:
                tally["bag_error_at_open"] += 1
                if "\n" in str(exc) or str(path) not in str(exc):
                    failures.append(f"{label}: BagError not one line naming the file: {exc}")
                reader = check = None
            except Exception as exc:  # noqa: BLE001 - the property under test
                tally["foreign_exceptions"] += 1
                failures.append(f"{label}: {type(exc).__name__}: {exc}")
                continue
            altered = [g for g in got if original.get(g[:3]) != g[3]]
            tally["altered_messages_returned"] += len(altered)
            if altered:
                failures.append(f"{label}: {len(altered)} altered messages returned")
            dupes = [k for k, v in Counter(g[:3] for g in got).items() if v > 1]
            if dupes:
                failures.append(f"{label}: messages returned twice {dupes[:2]}")
            returned = {g[:3] for g in got}
            for (a, b), keys in per_chunk.items():
                if b > len(damaged) or any(s < b and a < e for s, e in ranges):
                    continue
                missing = [k for k in keys if k not in returned]
                tally["intact_chunk_messages"] += len(keys)
                tally["intact_chunk_messages_missing"] += len(missing)
                if missing:
                    failures.append(f"{label}: {len(missing)} messages of the intact chunk at {a} missing")
            if reader is not None and len(got) < len(original):
                tally["variants_losing_messages"] += 1
                if not (reader.damage or reader.truncated):
                    failures.append(f"{label}: messages missing but no damage reported")
                if check.ok:
                    failures.append(f"{label}: verify() says OK on a bag that lost messages")
            if reader is not None and tally["variants"] % 4 == 0:  # strict mode: all or a BagError
                try:
                    strict = [m.data for m in BagReader(path, strict=True).messages()]
                    if len(strict) != len(original):
                        failures.append(f"{label}: strict reader returned a partial bag without error")
                except BagError:
                    tally["strict_bag_errors"] += 1
                except Exception as exc:  # noqa: BLE001 - the property under test
                    failures.append(f"{label}: strict: {type(exc).__name__}: {exc}")
            tally["messages_returned"] += len(got)
            tally["messages_lost"] += len(original) - len(got)
    return tally, failures


#: Damaged variants per source (224 in all, a fixed set: the seeds are fixed).
def test_fuzzed_bags_never_return_altered_data(sources, tmp_path):
    tally, failures = run_fuzz(sources, COUNTS, tmp_path)
    print(dict(tally))
    assert tally["variants"] >= 200
    assert tally["foreign_exceptions"] == 0 and tally["altered_messages_returned"] == 0
    assert tally["intact_chunk_messages"] > 1000 and tally["intact_chunk_messages_missing"] == 0
    assert not failures, "\n".join(failures[:20])
