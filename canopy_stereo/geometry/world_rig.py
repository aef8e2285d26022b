"""World-rig calibration from photographs of a chessboard at known places (paper sec. 2.1).

The paper calibrates both cameras in one world frame: an A0 sheet on the floor
carries a 2D x-z coordinate system with three lines through its origin (the
middle line and two lines turned -10 and +10 degrees about the origin, marks
every 50 mm), a vertical chessboard stands at known marks, and the world
coordinates of its inner corners follow from where it stands. The Gold Standard
algorithm (normalised DLT + Levenberg-Marquardt,
:func:`~canopy_stereo.geometry.calibration.gold_standard_projection`) then gives
``P_left`` and ``P_right`` from the detected corners.

The placements and the corners' world coordinates: :mod:`~canopy_stereo.geometry.board_placements`;
the corners: :mod:`~canopy_stereo.geometry.board_corners`; which detected corner is which:
:mod:`~canopy_stereo.geometry.corner_order`.

World frame and unit: those of the placements (the paper: millimetres, x
across, y down, z away from the cameras along the middle line).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CalibrationError
from canopy_stereo.geometry.board_corners import detect_board_corners
from canopy_stereo.geometry.board_placements import Placements, board_world_points, parse_pattern
from canopy_stereo.geometry.calibration import (
    TriangulationCheck,
    gold_standard_projection,
)
from canopy_stereo.geometry.camera import camera_centre, project
from canopy_stereo.geometry.chessboard import image_array, image_sequence
from canopy_stereo.geometry.corner_order import resolve_corner_order
from canopy_stereo.geometry.rig import Rig
from canopy_stereo.geometry.triangulation import triangulate_dlt


# ----------------------------------------------------------------------------- calibration
@dataclass
class WorldRigCalibration:
    """Result of :func:`calibrate_world_rig` (world frame and unit of the placements).

    Attributes:
        rig: the calibrated :class:`~canopy_stereo.geometry.rig.Rig` (no lens distortion:
            the Gold Standard model is linear, as in the paper).
        rms_left, rms_right: reprojection RMS of all used corners, pixels.
        used_pairs: pair indices whose board was found in both images.
        skipped: ``[(pair, reason)]`` pairs left out (board not found, no placement).
        pair_names: ``{pair: (left name, right name)}`` of every image pair.
        orientation_left, orientation_right: ``{pair: symmetry}`` applied to OpenCV's
            corners (``"as detected"``, ``"turned 180 degrees"``, ...).
        placement_rms_left, placement_rms_right: ``{pair: RMS px}`` per used pair.
        world_points: (N, 3) world corners of the used pairs (world units).
        corners_left, corners_right: (N, 2) their detected pixels, in world order.
        point_pair: (N,) pair index of each corner.
        table1: leave-one-placement-out check (the paper's Table 1 and Figure 5):
            every used pair's corners triangulated with the rig calibrated WITHOUT
            that pair; ``errors`` (N, 3) ``X_act - X_est`` and ``distance`` (N,) from
            the midpoint of the camera centres, world units.
        fit_check: the same with the rig fitted on all pairs (optimistic).
    """

    rig: Rig
    rms_left: float
    rms_right: float
    used_pairs: list
    skipped: list
    pair_names: dict
    orientation_left: dict
    orientation_right: dict
    placement_rms_left: dict
    placement_rms_right: dict
    world_points: np.ndarray
    corners_left: np.ndarray
    corners_right: np.ndarray
    point_pair: np.ndarray
    table1: TriangulationCheck
    fit_check: TriangulationCheck
    unit: str = "mm"
    extra: dict = field(default_factory=dict)

    @property
    def P_left(self) -> np.ndarray:
        return self.rig.P_left

    @property
    def P_right(self) -> np.ndarray:
        return self.rig.P_right

    def table(self) -> str:
        """The paper's Table 1 as text (leave-one-placement-out, world units)."""
        u = self.unit
        t = self.table1
        lines = [f"Table 1 (leave-one-placement-out, {len(t.errors)} corners of {len(self.used_pairs)} pairs)",
                 f"axis  mean |X_act - X_est| ({u})  std ({u})  max ({u})"]
        for i, axis in enumerate("XYZ"):
            lines.append(f"{axis:>4}  {t.mean_abs[i]:>24.3f}  {t.std[i]:>9.3f}  {t.max_abs[i]:>8.3f}")
        return "\n".join(lines)

    def summary(self) -> dict:
        """JSON-ready numbers: RMS per camera, Table 1 (mean abs, std of abs, max per axis), pairs."""
        t = self.table1
        return {
            "unit": self.unit,
            "rms_left_px": self.rms_left,
            "rms_right_px": self.rms_right,
            "pairs_used": list(self.used_pairs),
            "pairs_skipped": [{"pair": p, "reason": r} for p, r in self.skipped],
            "table1": {axis: {"mean_abs": float(t.mean_abs[i]), "std": float(t.std[i]),
                              "max_abs": float(t.max_abs[i])} for i, axis in enumerate("XYZ")},
            "corners_reordered": {
                "left": sum(1 for v in self.orientation_left.values() if v != "as detected"),
                "right": sum(1 for v in self.orientation_right.values() if v != "as detected")},
        }


def calibrate_world_rig(left_images, right_images, placements: Placements, *, pattern=None,
                        square: float | None = None, max_rms_px: float = 3.0,
                        leave_one_out: bool = True, detections=None, image_size=None,
                        progress=None) -> WorldRigCalibration:
    """Calibrate both cameras in the placements' world frame from chessboard photographs.

    Corners are detected with sub-pixel refinement in both images of every pair
    (:func:`detect_board_corners`), put into world order
    (:func:`resolve_corner_order`, per camera), given their world coordinates
    from the pair's placement (:func:`board_world_points`), and the Gold
    Standard algorithm (:func:`~canopy_stereo.geometry.calibration.gold_standard_projection`)
    gives ``P_left`` and ``P_right``.

    Args:
        left_images, right_images: sequences of (H, W[, 3]) uint8 arrays (for files:
            :class:`canopy_stereo.io.images.ImageFiles` of a glob, read one pair at a time,
            its file names naming the pairs); pair ``k`` is the k-th left and k-th right image.
        placements: :class:`Placements` (one per pair it covers).
        pattern: ``(cols, rows)`` inner corners; must agree with the placements (default theirs).
        square: square side in world units; must agree with the placements (default theirs).
        max_rms_px: reprojection tolerance (pixels) above which a pair contradicts its placement.
        leave_one_out: compute Table 1 leave-one-placement-out (else ``table1`` is the fit check).
        detections: optional precomputed ``{pair: (left (M, 2) | None, right (M, 2) | None)}``
            corners in OpenCV's (any) order, instead of detecting them in the images
            (the images may then be None).
        image_size: ``(width, height)`` written to the rig when no image is read
            (default: the images' size).
        progress: optional callable ``progress(message)``.

    Returns:
        :class:`WorldRigCalibration`.

    Raises:
        CalibrationError: pattern/square disagree with the placements; left and right
            counts or image sizes differ; a placement names a pair that has no images;
            the board is found in fewer than 3 pairs; a pair contradicts its placement.
    """
    say = progress or (lambda _m: None)
    pat = placements.pattern if pattern is None else parse_pattern(pattern)
    if pat != placements.pattern:
        raise CalibrationError(f"pattern {pat[0]}x{pat[1]} does not match the placements' "
                               f"{placements.pattern[0]}x{placements.pattern[1]}")
    sq = placements.square if square is None else float(square)
    if abs(sq - placements.square) > 1e-9 * max(1.0, abs(sq)):
        raise CalibrationError(f"square {sq:g} does not match the placements' {placements.square:g}")
    lefts, left_names = image_sequence(left_images, "left")
    rights, right_names = image_sequence(right_images, "right")
    if len(lefts) != len(rights):
        raise CalibrationError(f"{len(lefts)} left images but {len(rights)} right images")
    n_pairs = len(lefts)
    by_pair = placements.by_pair()
    beyond = [p for p in by_pair if p >= n_pairs]
    if beyond:
        raise CalibrationError(f"the placements place pair {beyond[0]} but there are only {n_pairs} "
                               f"image pairs (0..{n_pairs - 1})")
    skipped, names, used = [], {}, []
    det_l, det_r = {}, {}
    size = None
    for k in range(n_pairs):
        ln, rn = left_names[k], right_names[k]
        names[k] = (ln, rn)
        if k not in by_pair:
            skipped.append((k, "no placement"))
            continue
        if detections is not None and k in detections:
            cl, cr = detections[k]
        else:
            gl, gr = image_array(lefts[k], ln), image_array(rights[k], rn)
            if gl.shape[:2] != gr.shape[:2]:
                raise CalibrationError(f"pair {k}: {ln} and {rn} differ in size")
            this = (gl.shape[1], gl.shape[0])
            if size is None:
                size = this
            elif size != this:
                raise CalibrationError(f"pair {k}: {ln} is {this[0]}x{this[1]}, expected {size[0]}x{size[1]}")
            cl, cr = detect_board_corners(gl, pat), detect_board_corners(gr, pat)
        if cl is None or cr is None:
            where = "either image" if cl is None and cr is None else ("the left image" if cl is None
                                                                       else "the right image")
            skipped.append((k, f"board not found in {where}"))
            say(f"pair {k} ({ln}, {rn}): board not found in {where}, skipped")
            continue
        det_l[k], det_r[k] = np.asarray(cl, np.float64), np.asarray(cr, np.float64)
        used.append(k)
    if image_size is not None:
        image_size = (int(image_size[0]), int(image_size[1]))
        if size is not None and size != image_size:
            raise CalibrationError(f"the images are {size[0]}x{size[1]}, not {image_size[0]}x{image_size[1]}")
        size = image_size
    if size is None:
        for k in range(len(lefts)):
            item = lefts[k]
            if item is not None and np.ndim(item) >= 2:
                size = (np.shape(item)[1], np.shape(item)[0])
                break
    if size is None:
        raise CalibrationError("image_size is needed when no image is given")
    if len(used) < 3:
        raise CalibrationError(
            f"the {pat[0]}x{pat[1]} board was found in both images of only {len(used)} pair(s); need at "
            "least 3 (check --pattern: inner corners, columns x rows)")
    say(f"board found in {len(used)} of {n_pairs} pairs; resolving the corner order")
    W = [board_world_points(by_pair[k], pat, sq) for k in used]
    vnames = [f"pair {k} ({names[k][0]}, {names[k][1]})" for k in used]
    ord_l = resolve_corner_order(W, [det_l[k] for k in used], pat, max_rms_px=max_rms_px,
                                 view_names=[v + " left" for v in vnames])
    ord_r = resolve_corner_order(W, [det_r[k] for k in used], pat, max_rms_px=max_rms_px,
                                 view_names=[v + " right" for v in vnames])
    XL = [det_l[k][ord_l.index[i]] for i, k in enumerate(used)]
    XR = [det_r[k][ord_r.index[i]] for i, k in enumerate(used)]
    X = np.vstack(W)
    xl, xr = np.vstack(XL), np.vstack(XR)
    point_pair = np.repeat(np.array(used), pat[0] * pat[1])
    say("Gold Standard calibration of both cameras")
    P_l, rms_l = gold_standard_projection(X, xl)
    P_r, rms_r = gold_standard_projection(X, xr)
    rig = Rig(P_left=P_l, P_right=P_r, image_size=size, world_unit=placements.unit)
    mid = 0.5 * (camera_centre(P_l) + camera_centre(P_r))
    dist = np.linalg.norm(X - mid, axis=1)
    fit = TriangulationCheck(errors=X - triangulate_dlt(P_l, P_r, xl, xr, drop_behind=False), distance=dist)
    if leave_one_out:
        errs = np.empty_like(X)
        for i, k in enumerate(used):
            if i % 10 == 0 or i == len(used) - 1:
                say(f"leave-one-placement-out: pair {k} ({i + 1}/{len(used)})")
            keep = point_pair != k
            Pl_i, _ = gold_standard_projection(X[keep], xl[keep], initial=P_l)
            Pr_i, _ = gold_standard_projection(X[keep], xr[keep], initial=P_r)
            sel = ~keep
            errs[sel] = X[sel] - triangulate_dlt(Pl_i, Pr_i, xl[sel], xr[sel], drop_behind=False)
        table1 = TriangulationCheck(errors=errs, distance=dist)
    else:
        table1 = fit
    per_l = {k: float(np.sqrt(np.mean(np.sum((project(P_l, W[i]) - XL[i]) ** 2, axis=1))))
             for i, k in enumerate(used)}
    per_r = {k: float(np.sqrt(np.mean(np.sum((project(P_r, W[i]) - XR[i]) ** 2, axis=1))))
             for i, k in enumerate(used)}
    return WorldRigCalibration(
        rig=rig, rms_left=float(rms_l), rms_right=float(rms_r), used_pairs=used, skipped=skipped,
        pair_names=names, orientation_left={k: ord_l.names[i] for i, k in enumerate(used)},
        orientation_right={k: ord_r.names[i] for i, k in enumerate(used)},
        placement_rms_left=per_l, placement_rms_right=per_r, world_points=X, corners_left=xl,
        corners_right=xr, point_pair=point_pair, table1=table1, fit_check=fit, unit=placements.unit)


def plot_world_rig_errors(calibration: WorldRigCalibration, path) -> Path:
    """The paper's Figure 5 (error in X, Y and Z against distance from the rig) as a PNG.

    Uses the leave-one-placement-out errors of ``calibration.table1``.
    """
    from canopy_stereo.geometry.chessboard import plot_triangulation_errors

    plot_triangulation_errors(calibration.table1, path, unit=calibration.unit)
    return Path(path)
