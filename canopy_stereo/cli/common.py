"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse

from canopy_stereo.errors import CanopyStereoError


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
