"""Tests of canopy_stereo.pipeline (reconstruction of a pair)."""
