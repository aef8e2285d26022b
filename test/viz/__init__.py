"""Tests of canopy_stereo.viz (pictures with units, the web viewer in a browser)."""
