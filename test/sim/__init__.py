"""Tests of canopy_stereo.sim (leaf geometry, scenes, ray-cast rendering)."""
