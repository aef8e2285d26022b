"""Test suite of canopy_stereo; sub-packages mirror the package (``test/<stage>/`` tests ``canopy_stereo/<stage>/``)."""
