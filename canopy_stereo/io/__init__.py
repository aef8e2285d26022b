"""File formats: rig files, images, PFM disparities, PLY clouds, Middlebury data."""
from canopy_stereo.io.images import check_pair, read_image, to_bgr, to_gray, write_image
from canopy_stereo.io.pfm import read_pfm, write_pfm
from canopy_stereo.io.ply import PointCloud, read_ply, write_ply
from canopy_stereo.io.rig import Rig, load_rig, rig_from_parameters, save_rig, unit_to_metres

__all__ = [
    "PointCloud", "Rig", "check_pair", "load_rig", "read_image", "read_pfm", "read_ply",
    "rig_from_parameters", "save_rig", "to_bgr", "to_gray", "unit_to_metres", "write_image",
    "write_pfm", "write_ply",
]
