"""Who and what a recording is: canopy_stereo's MCAP metadata records.

A raw stereo bag describes itself with two MCAP metadata records (string ->
string maps, beside rosbag2's own ``rosbag2`` record, ignored by ``ros2 bag``):

* ``canopy_stereo`` (:data:`METADATA_RECORD`): free ``KEY=VALUE`` pairs given
  at recording time (``bag_record --metadata plant_id=A12 plot=row1
  treatment=drought date=2026-05-04``). Keys are letters, digits, ``_``, ``-``
  and ``.``; ``date`` is best given as ISO 8601 (``YYYY-MM-DD``), which sorts.
  The same pairs go into rosbag2's own ``custom_data`` (in the ``rosbag2``
  record, written when the bag is closed); a bag recorded by ``ros2 bag record
  --custom-data KEY=VALUE`` has only that, and it is read as well.
* ``canopy_stereo_rig`` (:data:`RIG_RECORD`): the rig file the cameras were
  recorded with, its full text under the key ``yaml`` (a ROS 2 parameter file,
  :func:`~canopy_stereo.io.rig.rig_to_yaml`), so that a bag is measured without
  a separate ``--rig``.

``canopy-stereo batch`` turns every key of ``canopy_stereo`` into a column of
its trait table and filters on them (``--select plot=row1``).

This module is the one reader and writer of both records: the recorders
(``bag_record --rig``, ``canopy_graph --record``) write them with
:func:`recording_metadata`; ``batch``, ``run`` and ``view`` read the rig with
:func:`canopy_metadata` / :func:`rig_from_bag`.
"""
from __future__ import annotations

import re

from canopy_stereo.errors import CanopyStereoError

#: Name of the metadata record holding the user's KEY=VALUE pairs.
METADATA_RECORD = "canopy_stereo"
#: Name of the metadata record holding the rig file.
RIG_RECORD = "canopy_stereo_rig"
#: Key of the rig file's text in :data:`RIG_RECORD`.
RIG_KEY = "yaml"

_KEY = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")


def parse_key_values(items, option: str = "--metadata") -> dict[str, str]:
    """``["plant_id=A12", "plot=row1"]`` -> ``{"plant_id": "A12", "plot": "row1"}``.

    A repeated key keeps its last value. Raises :class:`CanopyStereoError` naming
    ``option`` for an item without ``=`` or with an invalid key.
    """
    out: dict[str, str] = {}
    for item in items or ():
        key, sep, value = str(item).partition("=")
        key = key.strip()
        if not sep:
            raise CanopyStereoError(f"{option} needs KEY=VALUE, got {item!r}")
        if not _KEY.match(key):
            raise CanopyStereoError(f"{option}: invalid key {key!r} (use letters, digits, _ - .; "
                                    "start with a letter or _)")
        out[key] = value.strip()
    return out


def parse_selection(items, option: str = "--select") -> dict[str, set[str]]:
    """``["plot=row1", "plot=row2", "treatment=dry"]`` -> ``{"plot": {"row1", "row2"},
    "treatment": {"dry"}}``: values of one key are alternatives, keys must all match."""
    out: dict[str, set[str]] = {}
    for item in items or ():
        key, value = next(iter(parse_key_values([item], option).items()))
        out.setdefault(key, set()).add(value)
    return out


def matches_selection(metadata: dict, selection: dict) -> bool:
    """True when ``metadata`` has, for every key of ``selection``, one of its values."""
    return all(k in metadata and str(metadata[k]) in values for k, values in selection.items())


def rig_record(rig, comment: str | None = None) -> dict[str, str]:
    """The :data:`RIG_RECORD` record of ``rig`` (a :class:`~canopy_stereo.io.rig.Rig`)."""
    from canopy_stereo.io.rig import rig_to_yaml

    return {RIG_KEY: rig_to_yaml(rig, comment)}


def recording_metadata(metadata: dict | None = None, rig=None) -> dict[str, dict[str, str]]:
    """The records a recorder writes: ``{METADATA_RECORD: metadata, RIG_RECORD: rig}``
    (each only when given), for ``BagWriter(metadata=...)``."""
    records: dict[str, dict[str, str]] = {}
    if metadata:
        records[METADATA_RECORD] = {str(k): str(v) for k, v in metadata.items()}
    if rig is not None:
        records[RIG_RECORD] = rig_record(rig, "stereo rig of this recording (canopy_stereo)")
    return records


def rosbag2_custom_data(record: dict) -> dict[str, str]:
    """The ``custom_data`` pairs of a ``rosbag2`` metadata record ({} when none or unreadable)."""
    import yaml

    try:
        info = yaml.safe_load(record.get("serialized_metadata", "")) or {}
    except yaml.YAMLError:
        return {}
    if isinstance(info, dict) and "rosbag2_bagfile_information" in info:
        info = info["rosbag2_bagfile_information"]
    custom = info.get("custom_data") if isinstance(info, dict) else None
    return {str(k): str(v) for k, v in custom.items()} if isinstance(custom, dict) else {}


def rig_from_bag(path):
    """The :class:`~canopy_stereo.io.rig.Rig` recorded in the bag ``path``'s
    :data:`RIG_RECORD`, or None when it has none. Raises
    :class:`~canopy_stereo.bag.errors.BagError` for a file that is not a readable bag and
    :class:`~canopy_stereo.errors.RigError` for a rig record that does not parse."""
    from canopy_stereo.bag.reader import BagReader

    with BagReader(path) as bag:
        return canopy_metadata(bag.metadata(), source=str(path))[1]


def canopy_metadata(records: dict, source: str = "bag"):
    """``(metadata, rig)`` from a bag's metadata records (``BagReader.metadata()``):
    the :data:`METADATA_RECORD` pairs (else rosbag2's ``custom_data``; ``{}`` when
    neither) and the
    :class:`~canopy_stereo.io.rig.Rig` of :data:`RIG_RECORD` (None when absent).
    A rig record that does not parse raises :class:`~canopy_stereo.errors.RigError`."""
    from canopy_stereo.io.rig import rig_from_yaml

    if METADATA_RECORD in records:
        meta = dict(records[METADATA_RECORD])
    else:
        meta = rosbag2_custom_data(records.get("rosbag2", {}))
    rig = None
    if RIG_RECORD in records:
        text = records[RIG_RECORD].get(RIG_KEY)
        if not text:
            raise CanopyStereoError(f"{source}: metadata record {RIG_RECORD} has no '{RIG_KEY}' key")
        rig = rig_from_yaml(text, source=f"{source}'s rig record")
    return meta, rig
