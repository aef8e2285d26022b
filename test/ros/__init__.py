"""Tests of canopy_stereo.ros (nodes in-process and as processes, messages, frames, launch)."""
