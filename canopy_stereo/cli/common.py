"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.io.image_codec import DEFAULT_JPEG_QUALITY


def parse_int_list(text: str, count: int, name: str, *, sep: str = ",") -> list[int]:
    """Parse ``"a,b,c"`` into ``count`` ints or raise :class:`CanopyStereoError`."""
    parts = [p for p in text.replace("x", sep).split(sep) if p.strip()]
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        raise CanopyStereoError(f"{name} must be {count} integers, got {text!r}") from None
    if len(vals) != count:
        raise CanopyStereoError(f"{name} must be {count} integers, got {text!r}")
    return vals


def add_rig_argument(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """``--rig RIG.yaml``: the rig file (ROS 2 parameter YAML)."""
    parser.add_argument("--rig", required=required, metavar="RIG.yaml",
                        help="rig file with P_left/P_right (ROS 2 parameter YAML)")


def check_world_unit(unit: str, flag: str = "--unit") -> str:
    """``unit`` if it is a world unit a rig file may declare, else :class:`CanopyStereoError`."""
    from canopy_stereo.io.rig import UNIT_TO_METRES

    if unit not in UNIT_TO_METRES:
        raise CanopyStereoError(f"{flag} must be one of {', '.join(UNIT_TO_METRES)}, got {unit!r}")
    return unit


def check_positive(value: float, flag: str) -> float:
    """``value`` if it is a finite number > 0, else :class:`CanopyStereoError`."""
    import math

    if not (math.isfinite(value) and value > 0):
        raise CanopyStereoError(f"{flag} must be a finite number > 0, got {value}")
    return value


def check_at_least(value: int, minimum: int, flag: str) -> int:
    """``value`` if it is ``>= minimum``, else :class:`CanopyStereoError`."""
    if value < minimum:
        raise CanopyStereoError(f"{flag} must be at least {minimum}, got {value}")
    return value


def add_compression_arguments(p) -> None:
    """``--compress-images`` and ``--jpeg-quality`` (bag_record, run, canopy_graph)."""
    p.add_argument("--compress-images", action="store_true",
                   help="store 8-bit images as <topic>/compressed (sensor_msgs/CompressedImage: JPEG, "
                        "PNG for masks; depth stays raw), as image_transport names them")
    p.add_argument("--jpeg-quality", type=int, default=DEFAULT_JPEG_QUALITY, metavar="Q",
                   help=f"JPEG quality 1-100 of --compress-images (default {DEFAULT_JPEG_QUALITY})")


def compression_from_args(args):
    """The :class:`~canopy_stereo.ros.compressed.RecordingCompression` the options ask for, or None."""
    if not getattr(args, "compress_images", False):
        return None
    from canopy_stereo.ros.compressed import RecordingCompression

    return RecordingCompression(quality=args.jpeg_quality)
