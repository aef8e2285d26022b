"""Tests of canopy_stereo.geometry (cameras, calibration, rectification, triangulation)."""
