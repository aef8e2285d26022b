"""World-rig calibration (paper sec. 2.1): placements, corner order, rendered rig, CLI."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from canopy_stereo.errors import CalibrationError, ImageError
from canopy_stereo.geometry.board_corners import detect_board_corners  # noqa: E402
from canopy_stereo.geometry.board_placements import (
    BoardPlacement,
    Placements,
    board_world_points,
    paper_layout_placements,
)
from canopy_stereo.geometry.camera import camera_centre, project
from canopy_stereo.geometry.corner_order import board_symmetries, resolve_corner_order
from canopy_stereo.geometry.triangulation import triangulate_dlt
from canopy_stereo.geometry.world_rig import calibrate_world_rig
from canopy_stereo.io.images import ImageFiles
from canopy_stereo.io.placements import load_placements, write_placements

# --------------------------------------------------------------------------- placements


def test_paper_layout_is_three_lines_of_fifteen_marks_50mm_apart():
    pl = paper_layout_placements()
    assert len(pl) == 45 and pl.pattern == (7, 5) and pl.square == 50.0 and pl.unit == "mm"
    assert pl.pairs == list(range(45))
    feet = []
    for p in pl:
        W = board_world_points(p, pl.pattern, pl.square)
        assert W.shape == (35, 3)
        # vertical board: all rows horizontal, columns along world y (down), 50 mm apart
        g = W.reshape(5, 7, 3)
        assert np.allclose(np.diff(g[:, :, 1], axis=1), 0)
        assert np.allclose(np.linalg.norm(np.diff(g, axis=1), axis=2), 50.0)
        assert np.allclose(np.diff(g, axis=0), [0, 50.0, 0])
        # lowest corner row 75 mm above the sheet (y = 0, y down)
        assert np.isclose(g[-1, 0, 1], -75.0)
        centre = g.mean(axis=(0, 1))
        feet.append([centre[0], centre[2]])
        # the board faces the origin: its normal is along the line
        n = np.cross(p.x_axis, p.y_axis)
        assert abs(np.dot(n, np.array([centre[0], 0, centre[2]]) / math.hypot(centre[0], centre[2]))) > 0.999
    feet = np.array(feet).reshape(3, 15, 2)
    for line, angle in zip(feet, (-10.0, 0.0, 10.0)):
        assert np.allclose(np.degrees(np.arctan2(line[:, 0], line[:, 1])), angle)
        assert np.allclose(np.linalg.norm(np.diff(line, axis=0), axis=1), 50.0)
        assert np.isclose(np.linalg.norm(line[0]), 1000.0)


def test_paper_layout_boards_are_inside_both_views_of_the_paper_rig(paper_rig):
    pl = paper_layout_placements()
    w, h = paper_rig.image_size
    for p in pl:
        # the squares' outer edge: one square beyond the outer inner corners
        ext = BoardPlacement(0, p.origin - 50 * p.x_axis - 50 * p.y_axis, p.x_axis, p.y_axis)
        box = board_world_points(ext, (9, 7), 50.0)
        for P in (paper_rig.P_left, paper_rig.P_right):
            uv = project(P, box)
            assert uv[:, 0].min() > 0 and uv[:, 0].max() < w - 1
            assert uv[:, 1].min() > 0 and uv[:, 1].max() < h - 1


def test_placements_file_round_trip(tmp_path):
    pl = paper_layout_placements(first_mark=800.0, marks_per_line=4)
    path = write_placements(pl, tmp_path / "p.yaml", comment="test layout")
    text = path.read_text()
    assert text.startswith("# test layout") and "pattern: 7x5" in text
    back = load_placements(path)
    assert back.pattern == pl.pattern and back.square == pl.square and back.unit == "mm"
    assert back.pairs == pl.pairs
    for a, b in zip(pl, back):
        assert np.allclose(a.origin, b.origin, atol=1e-3) and np.allclose(a.x_axis, b.x_axis, atol=1e-6)
        assert np.allclose(a.y_axis, b.y_axis, atol=1e-6) and a.label == b.label


GOOD = {"pattern": "7x5", "square": 40, "unit": "mm",
        "placements": [{"pair": 0, "origin": [0, 0, 500], "x_axis": [1, 0, 0], "y_axis": [0, 1, 0]}]}


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["placements"][0].update(x_axis=[2, 0, 0]), "x_axis must be a unit vector"),
    (lambda d: d["placements"][0].update(y_axis=[0.6, 0.8, 0]), "must be orthogonal"),
    (lambda d: d["placements"][0].pop("origin"), "missing origin"),
    (lambda d: d["placements"][0].update(origin=[0, 0]), "origin must be a list of 3 numbers"),
    (lambda d: d["placements"][0].update(origin=[0, "a", 1]), "origin must be a list of 3 numbers"),
    (lambda d: d["placements"][0].update(pair=-1), "pair must be an integer >= 0"),
    (lambda d: d["placements"][0].update(axis=[1, 0, 0]), "unknown key(s) axis"),
    (lambda d: d["placements"].append(dict(d["placements"][0])), "pair 0 is already placed"),
    (lambda d: d.update(pattern="7by5"), "pattern must be COLSxROWS"),
    (lambda d: d.update(square=-4), "square must be a positive number"),
    (lambda d: d.update(unit="furlong"), "unknown unit 'furlong'"),
    (lambda d: d.update(placements=[]), "'placements' must be a non-empty list"),
    (lambda d: d.pop("square"), "missing 'square'"),
])
def test_load_placements_names_the_problem(tmp_path, mutate, message):
    import copy

    doc = copy.deepcopy(GOOD)
    mutate(doc)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CalibrationError) as info:
        load_placements(path)
    assert message in str(info.value) and str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_load_placements_rejects_bad_yaml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("pattern: [7, 5\nsquare: 4")
    with pytest.raises(CalibrationError, match="not valid YAML"):
        load_placements(bad)
    with pytest.raises(CalibrationError, match="cannot read placements file"):
        load_placements(tmp_path / "missing.yaml")
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(GOOD))
    assert len(load_placements(good)) == 1


# --------------------------------------------------------------------------- corner order


def _as_opencv(x, sym_index):
    """Detections in an order that ``sym_index`` maps back to the world order."""
    out = np.empty_like(x)
    out[sym_index] = x
    return out


def _synthetic_detections(rig, pl, rng, noise=0.03, turn_probability=0.5):
    syms = board_symmetries(pl.pattern)
    assert syms[1][0] == "turned 180 degrees"
    det, turned = {}, {}
    for p in pl:
        W = board_world_points(p, pl.pattern, pl.square)
        pair, flags = [], []
        for P in (rig.P_left, rig.P_right):
            x = project(P, W) + rng.normal(0, noise, (len(W), 2))
            t = bool(rng.random() < turn_probability)
            pair.append(_as_opencv(x, syms[1][1]) if t else x)
            flags.append(t)
        det[p.pair], turned[p.pair] = tuple(pair), flags
    return det, turned


@pytest.mark.slow
def test_symmetric_board_reversed_detections_get_the_right_order(paper_rig, rng):
    """7x5 (both odd) looks the same turned 180 degrees; half the detections are reversed."""
    pl = paper_layout_placements()
    det, turned = _synthetic_detections(paper_rig, pl, rng)
    assert 10 < sum(t[0] for t in turned.values()) < 35
    blank = [np.zeros((480, 640), np.uint8)] * len(pl)
    cal = calibrate_world_rig(blank, blank, pl, detections=det, leave_one_out=False)
    for k in pl.pairs:
        assert (cal.orientation_left[k] == "turned 180 degrees") == turned[k][0]
        assert (cal.orientation_right[k] == "turned 180 degrees") == turned[k][1]
    assert cal.rms_left < 0.06 and cal.rms_right < 0.06
    assert np.linalg.norm(camera_centre(cal.P_left) - camera_centre(paper_rig.P_left)) < 2.0


def test_corner_order_resolves_a_mirror_symmetric_layout_by_handedness(paper_rig, rng):
    """All boards of the paper layout share their row heights, so a mirror image of the
    layout (rows flipped top-bottom) fits as well as the truth: only the handedness of a
    real camera tells them apart."""
    pl = paper_layout_placements()
    W = [board_world_points(p, pl.pattern, pl.square) for p in pl]
    syms = board_symmetries(pl.pattern)
    flipped = dict(syms)["mirrored top-bottom"]
    D = [_as_opencv(project(paper_rig.P_left, w), flipped) for w in W]
    order = resolve_corner_order(W, D, pl.pattern)
    assert set(order.names) == {"mirrored top-bottom"}
    assert np.all(order.rms < 1e-6)


def test_corner_order_of_boards_on_one_axis_is_reported_ambiguous(paper_rig):
    """Boards on the middle line only, all facing along it: turning every board 180
    degrees about that line is explained by a camera turned about it."""
    pl = paper_layout_placements(angles_deg=(0.0,))
    W = [board_world_points(p, pl.pattern, pl.square) for p in pl]
    D = [project(paper_rig.P_left, w) for w in W]
    with pytest.raises(CalibrationError, match="ambiguous"):
        resolve_corner_order(W, D, pl.pattern)


def test_contradicting_placement_is_named(paper_rig, rng):
    pl = paper_layout_placements()
    det, _ = _synthetic_detections(paper_rig, pl, rng)
    moved = [BoardPlacement(p.pair, p.origin + (np.array([0, 0, 120.0]) if p.pair == 17 else 0),
                            p.x_axis, p.y_axis) for p in pl]
    bad = Placements(pl.pattern, pl.square, pl.unit, tuple(moved))
    blank = [np.zeros((480, 640), np.uint8)] * len(pl)
    with pytest.raises(CalibrationError, match=r"pair 17 .*contradicts its placement"):
        calibrate_world_rig(blank, blank, bad, detections=det, leave_one_out=False)


def test_skipped_pairs_are_listed(paper_rig, rng):
    pl = paper_layout_placements(marks_per_line=4)
    det, _ = _synthetic_detections(paper_rig, pl, rng)
    det[3] = (det[3][0], None)
    det[5] = (None, None)
    blank = [np.zeros((480, 640), np.uint8)] * (len(pl) + 1)   # one pair has no placement
    cal = calibrate_world_rig(blank, blank, pl, detections=det)
    assert dict(cal.skipped) == {3: "board not found in the right image",
                                 5: "board not found in either image", 12: "no placement"}
    assert 3 not in cal.used_pairs and len(cal.used_pairs) == 10
    assert len(cal.table1.errors) == 10 * 35


def test_pattern_and_square_must_agree_with_the_placements():
    pl = paper_layout_placements(marks_per_line=2)
    blank = [np.zeros((480, 640), np.uint8)] * len(pl)
    with pytest.raises(CalibrationError, match="pattern 9x6 does not match"):
        calibrate_world_rig(blank, blank, pl, pattern=(9, 6))
    with pytest.raises(CalibrationError, match="square 40 does not match"):
        calibrate_world_rig(blank, blank, pl, square=40)
    with pytest.raises(CalibrationError, match="found in both images of only 0 pair"):
        calibrate_world_rig(blank, blank, pl)


# --------------------------------------------------------------------------- rendered rig

#: Every third mark of the paper layout: 5 per line, 15 pairs (rendering all 45 takes minutes).
RENDERED_PAIRS = list(range(0, 45, 3))


@pytest.fixture(scope="module")
def rendered(paper_rig):
    """The paper's rig photographing a 7x5 board (180-degree symmetric) at 15 of the
    paper layout's places: 0.7 px blur, noise sigma 2 grey levels."""
    from canopy_stereo.sim.calibration import calibration_placements, render_calibration_scene

    pl = calibration_placements(paper_rig).subset(RENDERED_PAIRS)
    pairs = render_calibration_scene(paper_rig, pl, blur_px=0.7, noise_sigma=2.0, seed=3, samples=9)
    return pl, pairs


@pytest.mark.slow
def test_rendered_board_corners_are_found_to_a_few_hundredths_of_a_pixel(paper_rig, rendered):
    pl, pairs = rendered
    assert pl.pattern == (7, 5)                  # both odd: looks the same turned 180 degrees
    errs = []
    for p, (left, right) in zip(pl, pairs):
        assert left.shape == (480, 640, 3) and left.dtype == np.uint8
        W = board_world_points(p, pl.pattern, pl.square)
        for img, P in ((left, paper_rig.P_left), (right, paper_rig.P_right)):
            c = detect_board_corners(img, pl.pattern)
            assert c is not None
            x = project(P, W)
            errs.append(min(np.sqrt(np.mean(np.sum((c - x) ** 2, 1))),
                            np.sqrt(np.mean(np.sum((c[::-1] - x) ** 2, 1)))))
    assert np.mean(errs) < 0.05, errs


@pytest.mark.slow
def test_rendered_world_rig_recovers_the_paper_matrices(paper_rig, rendered):
    """Must show (issue 18): the recovered matrices triangulate points of the working
    volume with mean absolute error <= 0.2 mm in X and Y and <= 0.5 mm in Z."""
    pl, pairs = rendered
    cal = calibrate_world_rig([p[0] for p in pairs], [p[1] for p in pairs], pl)
    assert cal.skipped == [] and cal.used_pairs == list(range(len(pl)))
    assert cal.rms_left < 0.06 and cal.rms_right < 0.06
    # the working volume: the box the boards' corners span, 9 x 9 x 9 points, seen exactly
    X = cal.world_points
    lo, hi = X.min(0), X.max(0)
    g = np.stack(np.meshgrid(*[np.linspace(lo[i], hi[i], 9) for i in range(3)], indexing="ij"),
                 -1).reshape(-1, 3)
    est = triangulate_dlt(cal.P_left, cal.P_right, project(paper_rig.P_left, g),
                          project(paper_rig.P_right, g), drop_behind=False)
    mae = np.abs(est - g).mean(axis=0)
    assert mae[0] <= 0.2 and mae[1] <= 0.2 and mae[2] <= 0.5, mae
    for P, P_true in ((cal.P_left, paper_rig.P_left), (cal.P_right, paper_rig.P_right)):
        assert np.linalg.norm(camera_centre(P) - camera_centre(P_true)) < 3.0
    # Table 1 (leave-one-placement-out, detected corners triangulated back): the depth error
    # grows with distance squared over a 30 mm baseline; X and Y stay well under a millimetre
    t = cal.table1
    assert t.errors.shape == (len(pl) * 35, 3)
    assert t.mean_abs[0] < 1.0 and t.mean_abs[1] < 1.0 and t.mean_abs[2] < 8.0
    assert t.mean_abs[2] > t.mean_abs[0]
    assert np.all(t.distance > 900) and np.all(t.distance < 1800)

    # OpenCV happened to return these boards in world order: reverse half of the detections
    # (as it may for any board) and the same rig must come out
    syms = dict(board_symmetries(pl.pattern))
    det = {}
    for k, (left, right) in enumerate(pairs):
        cl, cr = detect_board_corners(left, pl.pattern), detect_board_corners(right, pl.pattern)
        det[k] = (cl[::-1].copy() if k % 2 else cl, cr if k % 3 else cr[::-1].copy())
    again = calibrate_world_rig([p[0] for p in pairs], [p[1] for p in pairs], pl, detections=det,
                                leave_one_out=False)
    assert syms["turned 180 degrees"].tolist() == list(range(34, -1, -1))
    flipped_l = [k for k, v in again.orientation_left.items() if v != cal.orientation_left[k]]
    flipped_r = [k for k, v in again.orientation_right.items() if v != cal.orientation_right[k]]
    assert flipped_l == [k for k in range(len(pl)) if k % 2] and flipped_r == [0, 3, 6, 9, 12]
    assert np.allclose(again.P_left, cal.P_left) and np.allclose(again.P_right, cal.P_right)


def _write_pairs(folder, pairs):
    from canopy_stereo.io.images import write_image

    folder.mkdir(parents=True, exist_ok=True)
    for k, (left, right) in enumerate(pairs):
        write_image(folder / f"left_{k:02d}.png", left)
        write_image(folder / f"right_{k:02d}.png", right)


@pytest.mark.slow
def test_cli_world_rig_calibration_and_contradicting_placements(tmp_path, cli, rendered, paper_rig):
    import cv2

    from canopy_stereo.io.rig import load_rig

    pl, pairs = rendered
    blank = np.full_like(pairs[0][0], 128)
    _write_pairs(tmp_path / "img", list(pairs) + [(pairs[0][0], blank)])   # pair 15: board only left
    extra = BoardPlacement(len(pl), pl[0].origin, pl[0].x_axis, pl[0].y_axis)
    placements = Placements(pl.pattern, pl.square, pl.unit, tuple(pl) + (extra,))
    write_placements(placements, tmp_path / "placements.yaml")
    left, right = str(tmp_path / "img" / "left_*.png"), str(tmp_path / "img" / "right_*.png")
    code, out, err = cli("calibrate", "--world-rig", tmp_path / "placements.yaml", left, right,
                         "--pattern", "7x5", "--square", "50", "-o", tmp_path / "rig.yaml",
                         "--plot", tmp_path / "err.png")
    assert code == 0, err
    assert "board found in 15 of 16 pairs" in out
    assert "skipped pair 15 (left_15.png, right_15.png): board not found in the right image" in out
    assert "reprojection RMS: left" in out and "Table 1" in out
    rig = load_rig(tmp_path / "rig.yaml")
    assert rig.image_size == (640, 480) and rig.world_unit == "mm"
    assert abs(rig.baseline - paper_rig.baseline) < 1.0
    plot = cv2.imread(str(tmp_path / "err.png"))
    assert plot is not None and plot.shape[1] > 800 and plot.std() > 10

    # a placements file that contradicts the images: pairs 3 and 9 swapped
    swapped = [BoardPlacement({3: 9, 9: 3}.get(p.pair, p.pair), p.origin, p.x_axis, p.y_axis)
               for p in pl]
    write_placements(Placements(pl.pattern, pl.square, pl.unit, tuple(swapped)), tmp_path / "bad.yaml")
    code, out, err = cli("calibrate", "--world-rig", tmp_path / "bad.yaml", left, right,
                         "--pattern", "7x5", "--square", "50", "-o", tmp_path / "bad_rig.yaml")
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "contradicts its placement" in lines[0], err
    assert not (tmp_path / "bad_rig.yaml").exists()

    # the board given on the command line disagrees with the file
    code, _, err = cli("calibrate", "--world-rig", tmp_path / "placements.yaml", left, right,
                       "--pattern", "9x6", "--square", "50", "-o", tmp_path / "x.yaml")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--pattern 9x6" in err


@pytest.mark.slow
def test_calibration_placements_follow_any_rig(repo_root):
    """The paper layout moved in front of another rig (its world frame and unit), far
    enough (and, for a narrow camera, with the side lines turned less) that every board
    is whole in both views."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.sim.calibration import boards_in_view, calibration_placements

    paper = load_rig(repo_root / "config" / "paper_rig.yaml")
    same = calibration_placements(paper)
    ref = paper_layout_placements()
    assert all(np.allclose(a.origin, b.origin) and a.label == b.label for a, b in zip(same, ref))
    assert boards_in_view(paper, same).all()
    other = load_rig(repo_root / "config" / "plants_rig.yaml")
    pl = calibration_placements(other)
    assert pl.unit == other.world_unit and len(pl) == 45
    assert boards_in_view(other, pl).all()
    assert not boards_in_view(other, ref).all()


def test_placements_for_missing_pairs_and_unequal_image_counts_are_rejected():
    pl = paper_layout_placements(marks_per_line=2)          # pairs 0..5
    blank = [np.zeros((480, 640), np.uint8)] * 4
    with pytest.raises(CalibrationError, match="place pair 4 but there are only 4 image pairs"):
        calibrate_world_rig(blank, blank, pl)
    with pytest.raises(CalibrationError, match="4 left images but 3 right images"):
        calibrate_world_rig(blank, blank[:3], pl)
    with pytest.raises(ImageError, match="no left images match"):   # files: ImageFiles (io)
        calibrate_world_rig(ImageFiles("/nonexistent/left_*.png", what="left images"),
                            ImageFiles("/nonexistent/right_*.png", what="right images"), pl)
    with pytest.raises(CalibrationError, match="is a path or glob; read the files with"):
        calibrate_world_rig("/nonexistent/left_*.png", "/nonexistent/right_*.png", pl)
