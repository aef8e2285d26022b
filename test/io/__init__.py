"""Tests of canopy_stereo.io and the MCAP bags (reader, writer, recorder, damage)."""
