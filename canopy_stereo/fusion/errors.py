"""Errors of multi-view fusion (all are user-fixable :class:`CanopyStereoError`)."""
from canopy_stereo.errors import CanopyStereoError


class RegistrationError(CanopyStereoError):
    """Views could not be registered: no overlap, too few consistent matches, or a poor fit."""


class UnitMismatchError(CanopyStereoError):
    """Views (or a pose file) are in different world units."""
