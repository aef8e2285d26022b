"""Reading the package's small YAML files (placements, poses): one line per problem."""
from __future__ import annotations

from pathlib import Path

import yaml

from canopy_stereo.errors import CanopyStereoError


def read_yaml_file(path, what: str, *, error: type[CanopyStereoError] = CanopyStereoError):
    """The parsed YAML document of the file at ``path``.

    Raises ``error`` (a :class:`~canopy_stereo.errors.CanopyStereoError`) naming ``what``
    (``"placements file"``, ``"pose file"``) and the path when the file cannot be read or
    is not valid YAML (first line of the parser's message).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"cannot read {what} {path}: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else "syntax error"
        raise error(f"{what} {path} is not valid YAML: {first}") from None
