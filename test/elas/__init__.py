"""Tests of canopy_stereo.elas (per stage and end to end)."""
