"""Tests of canopy_stereo.disparity (metrics, registry)."""
