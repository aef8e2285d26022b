"""Exceptions for problems with the user's input.

Every error a user can cause (a bad file, a bad matrix, mismatched images) is a
:class:`CanopyStereoError` with a message that names the problem. The CLI prints
that message as one line and exits non-zero; ROS nodes log it and drop the message.
"""


class CanopyStereoError(ValueError):
    """Base class: invalid input that the user can fix."""


class RigError(CanopyStereoError):
    """A rig file or camera matrix is missing, malformed or degenerate."""


class ImageError(CanopyStereoError):
    """An image cannot be read, has the wrong type, or does not match its partner."""


class CalibrationError(CanopyStereoError):
    """Calibration input is insufficient or degenerate."""


class MatchingError(CanopyStereoError):
    """Correspondence search found too little to continue."""
