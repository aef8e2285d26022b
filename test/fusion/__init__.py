"""Tests of canopy_stereo.fusion (registration, pose graph, voxel fusion)."""
