"""Tests of canopy_stereo.skew (capture-skew compensation) on simulated moving rigs."""
