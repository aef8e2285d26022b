"""Tests of canopy_stereo.measure (leaves and canopy against exact answers)."""
