"""Tests of canopy_stereo.segmentation (indices, GrabCut, automatic masks)."""
