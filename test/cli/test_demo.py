"""``canopy-stereo demo``: the Middlebury Plants bag through the node graph: PLY, pictures, summary."""
import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

pytestmark = pytest.mark.ros


@pytest.mark.slow
def test_cli_demo_writes_ply_disparity_png_and_summary(tmp_path, cli):
    from canopy_stereo.io.images import read_image
    from canopy_stereo.io.ply import read_ply

    code, stdout, stderr = cli("demo", "--scene", "plants", "--out", tmp_path)
    assert code == 0, stderr
    cloud = read_ply(tmp_path / "plants.ply")
    assert cloud.unit == "mm" and len(cloud) > 100_000 and cloud.colors.shape == (len(cloud), 3)
    # Middlebury Plants: the plants stand about 2 to 3 m from the cameras
    assert 1500 < np.median(cloud.points[:, 2]) < 3500
    plant = read_ply(tmp_path / "plants_plant.ply")  # the plant-only cloud: a part of the whole
    assert plant.unit == "mm" and 10_000 < len(plant) < len(cloud)
    from canopy_stereo.viz.colour import picture_offset

    png = read_image(tmp_path / "plants_disparity.png")  # the map, with a title and a colour bar
    y0, _ = picture_offset((496, 710))
    assert png.shape[0] == 496 + y0 + 6 and png.shape[1] > 710
    assert (tmp_path / "plants_mask.png").is_file() and (tmp_path / "plants_depth.png").is_file()
    summary = (tmp_path / "plants_summary.txt").read_text()
    assert "frames in: 1, frames out: 1" in summary and "points" in summary
    assert "measured: the automatic plant mask" in summary and "canopy: height" in summary
    assert "leaves measured:" in summary and (tmp_path / "plants_overlay.png").is_file()
    assert "no figure after warm-up" in summary
    assert "scene plants" in stdout
