"""Argument helpers shared by the subcommands."""
from __future__ import annotations

import argparse

from canopy_stereo.errors import CanopyStereoError


def parse_int_list(text: str, count: int, name: str, sep: str = ",") -> list[int]:
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
