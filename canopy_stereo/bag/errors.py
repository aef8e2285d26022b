"""The bag library's one error type and how an exception becomes one line of it."""
from __future__ import annotations

from canopy_stereo.errors import CanopyStereoError


class BagError(CanopyStereoError):
    """A bag file cannot be read or written."""


def _one_line(exc) -> str:
    text = " ".join(str(exc).split())
    return text[:200] if text else type(exc).__name__
