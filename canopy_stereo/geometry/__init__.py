"""Projective geometry: camera model, calibration, rectification, triangulation."""
