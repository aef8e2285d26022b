"""Split recordings (rosbag2-style): the files' names and the ``--split-size`` /
``--split-duration`` options of the recorders."""
from __future__ import annotations

import re
from pathlib import Path

from canopy_stereo.errors import CanopyStereoError


def split_file_path(path, index: int) -> Path:
    """The ``index``-th file of a split recording: ``out.mcap`` -> ``out_<index>.mcap``
    (rosbag2 names split files ``<name>_0.mcap``, ``<name>_1.mcap``, ...)."""
    path = Path(path)
    suffix = path.suffix or ".mcap"
    return path.with_name(f"{path.stem if path.suffix else path.name}_{int(index)}{suffix}")


_SIZE_UNITS = {"": 1, "B": 1, "K": 1 << 10, "KB": 1 << 10, "KIB": 1 << 10, "M": 1 << 20, "MB": 1 << 20,
               "MIB": 1 << 20, "G": 1 << 30, "GB": 1 << 30, "GIB": 1 << 30}


def parse_size(text) -> int:
    """Bytes from ``"1048576"``, ``"500M"``, ``"2G"``, ``"64KiB"`` (binary units)."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([A-Za-z]*)\s*", str(text))
    if not m or m.group(2).upper() not in _SIZE_UNITS:
        raise CanopyStereoError(f"size {text!r} is not a number of bytes (e.g. 500M, 2G)")
    return int(float(m.group(1)) * _SIZE_UNITS[m.group(2).upper()])


def add_split_arguments(parser) -> None:
    """``--split-size`` and ``--split-duration`` (rosbag2-style bag splitting) for a recorder."""
    parser.add_argument("--split-size", default="0", metavar="BYTES",
                        help="start a new file <name>_N.mcap when the current one reaches this "
                             "size (e.g. 500M, 2G; default 0 = never)")
    parser.add_argument("--split-duration", type=float, default=0.0, metavar="S",
                        help="start a new file <name>_N.mcap every S seconds of recording "
                             "(default 0 = never)")


def split_options(args) -> dict:
    """``{"split_size": ..., "split_duration_s": ...}`` from :func:`add_split_arguments` options
    (:class:`~canopy_stereo.errors.CanopyStereoError` for bad values)."""
    size = parse_size(args.split_size)
    duration = float(args.split_duration)
    if not duration >= 0 or duration == float("inf"):
        raise CanopyStereoError(f"--split-duration must be a finite number >= 0, got {args.split_duration}")
    return {"split_size": size, "split_duration_s": duration}
