"""Reading the package's small YAML files (rigs, parameter files, placements, poses): one line
per problem."""
from __future__ import annotations

from pathlib import Path

import yaml

from canopy_stereo.errors import CanopyStereoError


def read_text_file(path, what: str, *, error: type[CanopyStereoError] = CanopyStereoError) -> str:
    """The UTF-8 text of the file at ``path``; raises ``error`` naming ``what`` and the path when
    it cannot be read (missing, a directory, no permission) or is not UTF-8 (the first bad byte)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} {path} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset "
                    f"{exc.start})") from None


def yaml_error_line(exc: yaml.YAMLError) -> str:
    """A YAML parser error in one line: the problem and where (``expected ',' or ']' ... at line 2``)."""
    problem = getattr(exc, "problem", None) or (str(exc).splitlines() or ["syntax error"])[0]
    mark = getattr(exc, "problem_mark", None)
    return f"{problem} at line {mark.line + 1}" if mark is not None else problem


def read_yaml_file(path, what: str, *, error: type[CanopyStereoError] = CanopyStereoError):
    """The parsed YAML document of the file at ``path``.

    Raises ``error`` (a :class:`~canopy_stereo.errors.CanopyStereoError`) naming ``what``
    (``"placements file"``, ``"pose file"``) and the path when the file cannot be read, is
    not UTF-8 or is not valid YAML (:func:`yaml_error_line`).
    """
    text = read_text_file(path, what, error=error)
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{what} {path} is not valid YAML: {yaml_error_line(exc)}") from None
