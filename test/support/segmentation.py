"""Segmentation test inputs and scores (test/segmentation, test/cli/test_segment.py)."""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.geometry.camera import camera_centre

#: The SGBM settings of the depth cue tests.
SGBM = {"block_size": 7, "p1": 8, "p2": 32}


def iou(a, b):
    """Intersection over union of two masks."""
    a, b = np.asarray(a).astype(bool), np.asarray(b).astype(bool)
    return (a & b).sum() / (a | b).sum()


def blob_scene(leaf_bgr=(40, 150, 60), seed=0, size=(240, 320)):
    """Textured soil-brown background with two leaf-shaped blobs; returns (image, truth)."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.empty((h, w, 3), np.float64)
    img[:] = (60, 90, 130)  # brown soil (BGR)
    img += cv2.GaussianBlur(rng.normal(0, 25, (h, w, 3)), (0, 0), 2)
    truth = np.zeros((h, w), np.uint8)
    cv2.ellipse(truth, (110, 120), (70, 35), 30, 0, 360, 1, -1)
    cv2.ellipse(truth, (220, 110), (55, 30), -40, 0, 360, 1, -1)
    leaf = np.asarray(leaf_bgr, np.float64) * (0.8 + 0.4 * rng.random((h, w, 1)))
    img = np.where(truth[..., None] > 0, leaf, img)
    return np.clip(img, 0, 255).astype(np.uint8), truth.astype(bool)


def plant_truth(sim):
    return np.isin(sim.labels_left, (1, 2, 6))


def sim_depth(sim, matcher="sgbm", params=SGBM):
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair

    rec = reconstruct_pair(sim.left, sim.right, sim.rig, matcher=matcher, matcher_params=params)
    return np.linalg.norm(rec.organized - camera_centre(sim.rig.P_left), axis=-1)
