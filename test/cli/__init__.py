"""Tests of the command line, one file per ``canopy-stereo`` command."""
