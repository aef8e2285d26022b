"""Plant segmentation: GrabCut from a rectangle or mask, automatic plant masks
from vegetation indices and depth (the one seeder: :mod:`.auto`), plants (not green
things) and their instances from shape, depth and learned colour (:mod:`.plants`,
:func:`segment_plants`), the overlay picture (:mod:`.overlay`), and mask cleaning. (Leaf
instances, which need the organized cloud, are :func:`canopy_stereo.measure.separate_leaves`.)"""
from canopy_stereo.segmentation.auto import (
    IMAGE_SEEDER,
    VIDEO_SEEDER,
    SeederSettings,
    auto_plant_mask,
    plant_mask,
    plant_seed,
    seed_labels,
    segment_plant,
)
from canopy_stereo.segmentation.cleaning import clean_mask_regions
from canopy_stereo.segmentation.colour_model import ColourGMM, colour_log_ratio, fit_colour_gmm
from canopy_stereo.segmentation.grabcut import grabcut_labels, grabcut_mask, grabcut_rect
from canopy_stereo.segmentation.indices import (
    chromaticity,
    excess_green,
    excess_green_minus_red,
    excess_red,
    otsu_threshold,
    vegetation_index,
)
from canopy_stereo.segmentation.masks import (
    parse_rect,
    read_leaf_ids,
    read_mask,
    write_leaf_ids,
    write_mask,
)
from canopy_stereo.segmentation.overlay import mask_overlay
from canopy_stereo.segmentation.plants import (
    PLANT_SEGMENTER,
    PlantSegmentation,
    PlantSegmenterSettings,
    plant_instances,
    segment_plants,
)

__all__ = [
    "IMAGE_SEEDER", "SeederSettings", "VIDEO_SEEDER", "plant_mask", "seed_labels", "segment_plant",
    "ColourGMM", "auto_plant_mask", "chromaticity", "clean_mask_regions", "colour_log_ratio",
    "excess_green", "fit_colour_gmm",
    "excess_green_minus_red", "excess_red", "grabcut_labels", "grabcut_mask", "grabcut_rect",
    "otsu_threshold", "parse_rect", "plant_seed", "read_leaf_ids", "read_mask",
    "vegetation_index", "write_leaf_ids", "write_mask",
    "PLANT_SEGMENTER", "PlantSegmentation", "PlantSegmenterSettings", "mask_overlay", "plant_instances",
    "segment_plants",
]
