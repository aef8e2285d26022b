"""Tests of canopy_stereo.bag: MCAP writer, reader, damage, repair, metadata records, time pairing."""
