"""Fixtures shared by the command tests."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.io.pfm import write_pfm
from canopy_stereo.sim.stereo_pair import shifted_pair


@pytest.fixture
def pair_files(tmp_path):
    left, right, gt = shifted_pair(160, 120, shift=11.0, seed=7)
    cv2.imwrite(str(tmp_path / "left.png"), left)
    cv2.imwrite(str(tmp_path / "right.png"), right)
    # ground truth as a PNG with scale 4 (0 = unknown) and as a PFM (inf = unknown)
    png = np.where(np.isfinite(gt), np.rint(gt * 4), 0).astype(np.uint8)
    cv2.imwrite(str(tmp_path / "gt.png"), png)
    write_pfm(tmp_path / "gt.pfm", np.where(np.isfinite(gt), gt, np.inf))
    return tmp_path
