"""Repair of a damaged or unclosed bag: every intact message copied into a complete one."""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.bag.check import BagCheck
from canopy_stereo.bag.errors import BagError
from canopy_stereo.bag.reader import BagReader
from canopy_stereo.bag.writer import BagWriter


def repair_bag(src, dst, *, compression: str | None = None, overwrite: bool = False) -> BagCheck:
    """Write every intact message of ``src`` (a damaged or unclosed bag) to a new, complete
    bag ``dst``; returns the check of ``src``. Metadata records that read intact (other than
    rosbag2's own, which is rewritten) are copied.

    Args:
        compression: chunk compression of ``dst`` (default: that of ``src``'s chunks, else zstd).
        overwrite: replace an existing ``dst``.
    """
    src, dst = Path(src), Path(dst)
    if dst.resolve() == src.resolve():
        raise BagError(f"{dst}: repair needs another output file than its input")
    reader = BagReader(src)
    if compression is None:
        comps = {c.compression for c in reader._chunks}
        compression = comps.pop() if len(comps) == 1 else "zstd"
        compression = compression or "none"
    writer = BagWriter(dst, compression=compression, overwrite=overwrite, flush_period_s=0)
    try:
        for topic, info in reader.topics.items():
            writer.add_topic(topic, info.type_name, qos_yaml=info.qos_yaml, definition=info.definition)
        for name, data in reader.metadata_records:
            if name != "rosbag2":
                writer.add_metadata(name, data)
        for m in reader.messages(log_time_order=True):
            writer.write(m.topic, m.data, m.log_time_ns, publish_time_ns=m.publish_time_ns,
                         msg_type=m.type_name)
    finally:
        writer.close()
    return reader.verify()
