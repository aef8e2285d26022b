"""Real pair: Middlebury 2014 "Plants" (../shared/data, no ground truth), end to end.

Reconstruct with the published calibration (world = left camera frame, mm),
segment automatically (ExG + depth), measure. Without ground truth the checks
are that everything runs and the sizes agree with the calibration: the plants
stand about 2 m from the cameras and are a few hundred millimetres tall.
"""
from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.slow
def test_plants_end_to_end(shared_data, tmp_path):
    from canopy_stereo.geometry.camera import camera_centre
    from canopy_stereo.io.middlebury import load_middlebury_2014
    from canopy_stereo.measure import measure_scene, write_report
    from canopy_stereo.pipeline.reconstruct import reconstruct_pair
    from canopy_stereo.segmentation import auto_plant_mask

    scene = load_middlebury_2014(shared_data / "middlebury_MiddEval3_testQ" / "Plants")
    rig = scene["rig"]
    rec = reconstruct_pair(scene["left"], scene["right"], rig, matcher="sgbm")
    dist = np.linalg.norm(rec.organized - camera_centre(rig.P_left), axis=-1)
    assert 1500 < np.nanmedian(dist) < 3500  # the scene is about 2 m away
    mask = auto_plant_mask(scene["left"], depth=dist, index="exg") > 0
    assert 0.15 < mask.mean() < 0.6
    res = measure_scene(rec.organized, mask=mask, unit=rig.world_unit, min_leaf_pixels=1500)
    rep = res.report
    assert rep["source"]["camera"] == "estimated"
    assert np.allclose(rep["source"]["camera_centre"], camera_centre(rig.P_left), atol=1.0)
    can = rep["canopy"]
    for key in ("height", "width", "depth", "hull_volume", "voxel_volume"):
        assert np.isfinite(can[key]) and can[key] > 0, key
    assert 150 < can["height"] < 1500 and 150 < can["width"] < 1500 and can["depth"] < 3000
    assert can["hull_volume"] < can["height"] * can["width"] * can["depth"]
    reliable = [lf for lf in rep["leaves"] if lf["reliable"]]
    # the ExG mask's 1500-pixel clusters on this scene are not single leaves: how many fit as
    # reliable leaves swings with the cloud (3 on the pair re-rectified to one principal point,
    # cut and resampled; 1 on the pair as given, which has 14 % more points; ELAS: 0 and 2)
    assert len(reliable) >= 1
    for lf in reliable:
        assert 0 < lf["width"] <= lf["length"] * 1.5 and lf["length"] < 600
        assert np.isfinite(lf["area"]) and lf["area"] > 0
    out = write_report(rep, tmp_path / "plants.json", csv=tmp_path / "plants.csv")
    assert out.stat().st_size > 1000
