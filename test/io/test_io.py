import numpy as np
import pytest

from canopy_stereo.errors import CanopyStereoError, ImageError, RigError
from canopy_stereo.io.images import check_pair, read_image
from canopy_stereo.io.pfm import read_pfm, write_pfm
from canopy_stereo.io.ply import read_ply, write_ply
from canopy_stereo.io.rig import load_rig, save_rig


def test_rig_round_trip(tmp_path, paper_rig):
    rig = paper_rig.with_extra(method="fusiello", disp_max=96)
    path = save_rig(rig, tmp_path / "r.yaml", comment="test")
    back = load_rig(path)
    assert np.array_equal(back.P_left, rig.P_left) and np.array_equal(back.P_right, rig.P_right)
    assert back.image_size == (640, 480) and back.world_unit == "mm"
    assert back.extra["disp_max"] == 96 and back.metres_per_unit == 0.001


@pytest.mark.parametrize("text, word", [
    ("a: [1, 2", "YAML"),
    ("/**:\n  ros__parameters:\n    P_left: [1, 2]\n", "missing"),
    ("/**:\n  ros__parameters:\n    image_width: 640\n    image_height: 480\n"
     "    P_left: [1,0,0,0, 0,1,0,0, 0,0,1,0]\n    P_right: [1,0,0,0, 0,1,0,0, 0,0,0,0]\n", "rank"),
    ("/**:\n  ros__parameters:\n    image_width: 640\n    image_height: 480\n"
     "    P_left: [.nan,0,0,0, 0,1,0,0, 0,0,1,0]\n    P_right: [1,0,0,0, 0,1,0,0, 0,0,1,0]\n", "non-finite"),
])
def test_bad_rig_files(tmp_path, text, word):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(RigError, match=word):
        load_rig(p)


def test_missing_rig_file(tmp_path):
    with pytest.raises(RigError, match="cannot read"):
        load_rig(tmp_path / "nope.yaml")


def test_ply_round_trip(tmp_path, rng):
    pts = rng.normal(size=(1000, 3)) * 100
    cols = rng.integers(0, 256, (1000, 3)).astype(np.uint8)
    path = write_ply(tmp_path / "c.ply", pts, colors=cols, unit="mm")
    cloud = read_ply(path)
    assert cloud.unit == "mm" and len(cloud) == 1000
    assert np.allclose(cloud.points, pts.astype(np.float32))
    assert np.array_equal(cloud.colors, cols)
    head = path.read_bytes()[:400]
    assert b"format binary_little_endian 1.0" in head and b"property uchar red" in head


def test_ascii_ply_and_bad_files(tmp_path):
    p = tmp_path / "a.ply"
    p.write_text("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                 "property float z\nend_header\n1 2 3\n4 5 6\n")
    assert np.allclose(read_ply(p).points, [[1, 2, 3], [4, 5, 6]])
    q = tmp_path / "n.ply"
    q.write_text("hello")
    with pytest.raises(CanopyStereoError, match="not a PLY"):
        read_ply(q)


def test_pfm_round_trip(tmp_path, rng):
    d = rng.uniform(0, 50, (7, 9)).astype(np.float32)
    d[0, 0] = np.inf
    back = read_pfm(write_pfm(tmp_path / "d.pfm", d))
    assert np.array_equal(back, d)


def test_images(tmp_path):
    with pytest.raises(ImageError, match="not found"):
        read_image(tmp_path / "missing.png")
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(ImageError, match="cannot read"):
        read_image(bad)
    with pytest.raises(ImageError, match="differ"):
        check_pair(np.zeros((4, 5)), np.zeros((5, 4)))


def test_middlebury_calib(shared_data):
    from canopy_stereo.io.middlebury import read_middlebury_calib, rig_from_middlebury

    c = read_middlebury_calib(shared_data / "middlebury_MiddEval3_testQ" / "Plants" / "calib.txt")
    assert c["doffs"] == pytest.approx(85.019) and c["baseline"] == pytest.approx(169.843)
    rig = rig_from_middlebury(c)
    assert rig.baseline == pytest.approx(169.843) and rig.image_size == (710, 496)


def test_ply_extra_vertex_properties(tmp_path, rng):
    pts = rng.normal(size=(50, 3))
    views = rng.integers(1, 9, 50).astype(np.uint8)
    counts = rng.integers(1, 10_000, 50).astype(np.uint32)
    path = write_ply(tmp_path / "e.ply", pts, properties={"views": views, "points": counts})
    head = path.read_bytes()[:400]
    assert b"property uchar views" in head and b"property uint points" in head
    cloud = read_ply(path)
    assert np.array_equal(cloud.extra["views"], views) and np.array_equal(cloud.extra["points"], counts)
    with pytest.raises(CanopyStereoError, match="views"):
        write_ply(tmp_path / "f.ply", pts, properties={"views": views[:3]})
