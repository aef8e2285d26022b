"""Tests of canopy_stereo.features (matchers, quasi-dense matching, the study)."""
