"""A bag of raw images -> the same bag with its images compressed, as robots record them.

``canopy-stereo bag compress FILE -o OUT [--jpeg-quality Q]`` and ``canopy-stereo demo
--compressed`` use :func:`compress_bag`: every message is copied with its times; each
8-bit ``sensor_msgs/Image`` topic becomes image_transport's ``<topic>/compressed``
(``CompressedImage``; JPEG at ``quality``, PNG for masks; others, e.g. a 16UC1 truth depth,
stay raw), by :class:`~canopy_stereo.ros.compressed.RecordingCompression`, the conversion
the recorders apply. Metadata records (plant, rig) are copied.
"""
from __future__ import annotations

from pathlib import Path

from canopy_stereo.bag import BagError, BagReader, BagWriter
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY
from canopy_stereo.ros.compressed import RecordingCompression


def compress_bag(src, dst, *, quality: int = DEFAULT_JPEG_QUALITY, overwrite: bool = False) -> dict[str, int]:
    """Write ``src`` to ``dst`` with its images compressed (see module docstring); returns
    ``{topic written: messages}``. Raises :class:`BagError` when ``src`` is damaged or cut
    short (``canopy-stereo bag repair`` it first) or ``dst`` is ``src``."""
    src, dst = Path(src), Path(dst)
    if dst.exists() and dst.resolve() == src.resolve():
        raise BagError(f"{dst}: compress needs another output file than its input")
    reader = BagReader(src)
    if reader.truncated or reader.damage:
        raise BagError(f"{src} is {'truncated' if reader.truncated else 'damaged'} ({reader.problem}): "
                       "repair it first (canopy-stereo bag repair)")
    compression = RecordingCompression(quality=quality)
    counts: dict[str, int] = {}
    writer = BagWriter(dst, overwrite=overwrite, flush_period_s=0)
    try:
        for name, data in reader.metadata_records:
            if name != "rosbag2":
                writer.add_metadata(name, data)
        for m in reader.messages(log_time_order=True):
            topic, tname, data = compression.convert(m.topic, m.type_name, m.data)
            if topic not in writer.topics:
                writer.add_topic(topic, tname, qos_yaml=reader.topics[m.topic].qos_yaml)
            writer.write(topic, data, m.log_time_ns, publish_time_ns=m.publish_time_ns, msg_type=tname)
            counts[topic] = counts.get(topic, 0) + 1
    finally:
        writer.close()
    return counts
