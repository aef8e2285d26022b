"""Tests of canopy_stereo.batch (``canopy-stereo batch`` on Dask)."""
