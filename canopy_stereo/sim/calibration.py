"""Rendered world-rig calibration scenes: the paper's chessboard layout seen through any rig.

The paper's calibration set-up (sec. 2.1, Figures 2-4) is rebuilt from the
simulator's primitives and rendered by its ray caster
(:func:`~canopy_stereo.sim.render.render_view`, supersampled anti-aliasing and
the rig's lens distortion) and sensor model
(:class:`~canopy_stereo.sim.sensor.CameraEffects`): the floor sheet (white
paper with a 50 mm grid and the three lines through the origin; world plane
``y = 0``), a vertical chessboard (black and white squares in a white margin)
at each placement, and a grey wall far behind. The optics blur the image with
a Gaussian of ``blur_px`` pixels before the sensor adds its noise.

    from canopy_stereo.sim.calibration import calibration_placements, render_calibration_scene
    placements = calibration_placements(rig)              # the paper's 45 placements
    pairs = render_calibration_scene(rig, placements)      # [(left, right)] uint8 BGR

For the paper's rig (``config/paper_rig.yaml``) the placements are exactly
:func:`~canopy_stereo.geometry.board_placements.paper_layout_placements` in the
paper's world frame; for any other rig the same layout is moved in front of
it (the paper rig's anchor frame onto this rig's, :func:`~canopy_stereo.sim.scene.rig_anchor`)
and expressed in the rig's world frame and unit.
"""
from __future__ import annotations

import math

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.board_placements import PAPER_LAYOUT, BoardPlacement, Placements, paper_layout_placements
from canopy_stereo.io.rig import unit_to_metres
from canopy_stereo.sim.primitives import LABEL_BACKGROUND, Material, Rectangle
from canopy_stereo.sim.render import render_view
from canopy_stereo.sim.scene import Scene, rig_anchor
from canopy_stereo.sim.sensor import CameraEffects, lattice_pattern
from canopy_stereo.sim.simulate import resolve_rig

#: White margin around the squares of the rendered board, in squares.
BOARD_MARGIN_SQUARES = 0.5


def _coprime_generator(count: int) -> int:
    """A lattice generator near ``0.3 count`` coprime with ``count`` (5 for 16)."""
    g = max(1, round(0.3 * count))
    while math.gcd(g, count) != 1:
        g += 1
    return g


def _layout_in_front_of(rig, paper, **layout) -> Placements:
    """The paper layout (mm, paper frame) moved from the paper rig's anchor frame to ``rig``'s."""
    base = paper_layout_placements(**layout)
    if base.unit != "mm":
        raise CanopyStereoError("calibration_placements builds the layout in millimetres; leave unit at mm")
    o_p, A_p = rig_anchor(paper)
    o_r, A_r = rig_anchor(rig)
    s = 0.001 / rig.metres_per_unit                     # mm -> rig unit
    Q = A_r.T @ A_p                                      # paper world -> rig world rotation
    same = (rig.world_unit == "mm" and np.allclose(Q, np.eye(3), atol=1e-12)
            and np.allclose(o_p, o_r, atol=1e-9))
    if same:
        return base
    out = []
    for p in base:
        origin = o_r + s * (Q @ (p.origin - o_p))
        out.append(BoardPlacement(p.pair, origin, Q @ p.x_axis, Q @ p.y_axis, p.label))
    return Placements(base.pattern, base.square * s, rig.world_unit, tuple(out))


def boards_in_view(rig, placements: Placements, *, margin_px: float = 2.0) -> np.ndarray:
    """(N,) bool: the whole board of each placement (its squares, one square beyond the
    outer inner corners) lies in front of both cameras and at least ``margin_px`` inside
    both images."""
    from canopy_stereo.geometry.board_placements import board_world_points
    from canopy_stereo.geometry.camera import project

    cols, rows = placements.pattern
    w, h = rig.image_size
    out = np.zeros(len(placements), bool)
    for k, p in enumerate(placements):
        ext = BoardPlacement(0, p.origin - placements.square * (p.x_axis + p.y_axis), p.x_axis, p.y_axis)
        box = board_world_points(ext, (cols + 2, rows + 2), placements.square)
        ok = True
        for P in (rig.P_left, rig.P_right):
            w_h = (np.column_stack([box, np.ones(len(box))]) @ P[2]) * np.sign(np.linalg.det(P[:, :3]))
            if np.any(w_h <= 0):
                ok = False
                break
            uv = project(P, box)
            if (uv[:, 0].min() < margin_px or uv[:, 1].min() < margin_px
                    or uv[:, 0].max() > w - 1 - margin_px or uv[:, 1].max() > h - 1 - margin_px):
                ok = False
                break
        out[k] = ok
    return out


def calibration_placements(rig=None, *, fit_to_view: bool = True, **layout) -> Placements:
    """The paper's layout (:func:`~canopy_stereo.geometry.board_placements.paper_layout_placements`,
    keyword options ``layout`` in millimetres) placed in front of ``rig``.

    The layout is moved from the paper rig's anchor frame to ``rig``'s
    (:func:`~canopy_stereo.sim.scene.rig_anchor`). With ``fit_to_view`` and no
    ``first_mark`` given, the first mark is the nearest multiple of 50 mm (from
    200 mm) at which every board is whole inside both views (:func:`boards_in_view`):
    1000 mm for the paper's rig, whose placements are then exactly the paper layout.
    A camera too narrow to see lines 10 degrees off the middle at any distance gets
    the side lines turned less (the labels say by how much).

    Args:
        rig: a :class:`~canopy_stereo.io.rig.Rig`, a rig path, or None (the paper's rig).

    Returns:
        :class:`~canopy_stereo.geometry.board_placements.Placements` in ``rig``'s world frame and unit.

    Raises:
        CanopyStereoError: no first mark up to 50 m puts every board in both views.
    """
    rig = resolve_rig(rig)
    paper = resolve_rig(None)
    if "first_mark" in layout or not fit_to_view:
        return _layout_in_front_of(rig, paper, **layout)
    angles = tuple(layout.pop("angles_deg", PAPER_LAYOUT["angles_deg"]))
    # the paper's angles first; a narrow camera that cannot see them gets the lines closer together
    for shrink in (1.0, 0.8, 0.6, 0.5, 0.4, 0.3, 0.2, 0.1, 0.0):
        ang = tuple(a * shrink for a in angles)

        def fits(first, ang=ang):
            placed = _layout_in_front_of(rig, paper, first_mark=float(first), angles_deg=ang, **layout)
            return placed if np.all(boards_in_view(rig, placed)) else None

        lo, hi = None, None
        first = 200.0
        while first <= 50000.0:          # coarse: 10 % steps
            if fits(first) is not None:
                hi = first
                break
            lo = first
            first *= 1.1
        if hi is None:
            continue
        start = 200.0 if lo is None else 50.0 * math.floor(lo / 50.0)
        for first in np.arange(start, hi + 50.0, 50.0):   # fine: the first 50 mm step that fits
            placed = fits(first)
            if placed is not None:
                return placed
    raise CanopyStereoError("the paper layout does not fit in both views of this rig at any distance up to "
                            "50 m: pass first_mark and angles_deg and check the rig")


def _board(placement: BoardPlacement, pattern, square: float, mm: float) -> Rectangle:
    cols, rows = pattern
    centre = placement.centre(pattern, square)
    axes = np.vstack([placement.x_axis, placement.y_axis, placement.normal])
    half_x = (0.5 * (cols + 1) + BOARD_MARGIN_SQUARES) * square
    half_y = (0.5 * (rows + 1) + BOARD_MARGIN_SQUARES) * square
    return Rectangle(centre, axes, half_x, half_y,
                     Material("checkerboard", 0, (square * mm, cols + 1.0, rows + 1.0)),
                     label=LABEL_BACKGROUND)


def calibration_scene(rig, placement: BoardPlacement, placements: Placements, *,
                      sheet: bool = True, seed: int = 0) -> Scene:
    """The :class:`~canopy_stereo.sim.scene.Scene` of one image pair: the board at
    ``placement``, the floor sheet (world plane ``y = 0`` of the paper's frame, moved
    with the layout for other rigs) and a wall behind everything.
    """
    rig = resolve_rig(rig)
    if placements.unit != rig.world_unit:
        raise CanopyStereoError(f"the placements are in {placements.unit} but the rig in {rig.world_unit}")
    mm = 1000.0 * unit_to_metres(rig.world_unit)        # mm per world unit
    prims = [_board(placement, placements.pattern, placements.square, mm)]
    o_a, A = rig_anchor(rig)
    pts = np.vstack([p.origin for p in placements])
    far = float(np.max((pts - o_a) @ A[2]))
    # the sheet: the plane through the boards' feet (paper frame: y = 0), grid + three lines
    o_p, A_p = rig_anchor(resolve_rig(None))
    Q = A.T @ A_p
    same = np.allclose(Q, np.eye(3), atol=1e-12) and np.allclose(o_a, o_p, atol=1e-9) and mm == 1.0
    s = 1.0 if same else 0.001 / rig.metres_per_unit
    origin = np.zeros(3) if same else o_a + s * (Q @ (np.zeros(3) - o_p))
    ex, ez, up = Q @ np.array([1.0, 0, 0]), Q @ np.array([0, 0, 1.0]), Q @ np.array([0, -1.0, 0])
    if sheet:
        half = 2.5 * far
        centre = origin + half * 0.5 * ez
        angle = 10.0
        prims.append(Rectangle(centre, np.vstack([ex, ez, up]), half, half,
                               Material("sheet", 0, (50.0, 1.0, 0.0, -0.5 * half * mm, angle, 4.0)),
                               label=LABEL_BACKGROUND))
    wall_at = o_a + 1.6 * far * A[2]
    wall = Rectangle(wall_at, np.vstack([A[0], A[1], -A[2]]), np.inf, np.inf,
                     Material("sheet", 0, (1e9, 0.0, 0.0, 0.0, 0.0, 0.0)), label=LABEL_BACKGROUND)
    prims.append(wall)
    light = A.T @ np.array([0.3, -0.6, -1.0])  # from above, behind the rig (anchor frame)
    return Scene(name="calibration", seed=int(seed), primitives=tuple(prims), background=wall,
                 light=light, ambient=0.55, diffuse=0.45, world_unit=rig.world_unit,
                 anchor_origin=o_a, anchor_axes=A)


def render_calibration_scene(rig, placements: Placements, *, blur_px: float = 0.7,
                             noise_sigma: float = 2.0, seed: int = 0, samples: int = 16,
                             effects: CameraEffects | None = None, sheet: bool = True,
                             progress=None) -> list:
    """Render every placement's image pair through ``rig``.

    Args:
        rig: :class:`~canopy_stereo.io.rig.Rig`, rig path, or None (the paper's rig).
        placements: :class:`~canopy_stereo.geometry.board_placements.Placements` in the rig's
            world frame and unit (e.g. :func:`calibration_placements`).
        blur_px: standard deviation (pixels) of the Gaussian optical blur applied to
            the scene radiance before the sensor (0 = none).
        noise_sigma: sensor noise, standard deviation in 8-bit grey levels.
        seed: noise seed (pair ``k`` draws from ``(seed, k)``).
        samples: anti-aliasing rays per pixel, a rank-1 lattice
            (:func:`~canopy_stereo.sim.sensor.lattice_pattern`; every ray in its own
            pixel row and column, which chessboard edges need).
        effects: full sensor model (overrides ``noise_sigma``); default
            ``CameraEffects(noise_sigma=noise_sigma)``.
        sheet: draw the floor sheet.
        progress: optional callable ``progress(message)``.

    Returns:
        list of ``(left, right)`` (H, W, 3) uint8 BGR images, in the placements' order
        (ascending ``pair``).
    """
    import cv2

    rig = resolve_rig(rig)
    if blur_px < 0 or not math.isfinite(blur_px):
        raise CanopyStereoError(f"blur_px must be >= 0, got {blur_px}")
    if effects is None:
        effects = CameraEffects(noise_sigma=float(noise_sigma))
    pattern = lattice_pattern(int(samples), _coprime_generator(int(samples)))
    out = []
    for n, placement in enumerate(placements):
        scene = calibration_scene(rig, placement, placements, sheet=sheet, seed=seed)
        scene.packed  # noqa: B018 - pack once
        rng = np.random.default_rng([int(seed) & 0x7FFFFFFF, int(placement.pair), 0xCA11B])
        images = []
        for cam, (P, D) in enumerate(((rig.P_left, rig.D_left), (rig.P_right, rig.D_right))):
            radiance = render_view(scene, P, D, rig.image_size, samples=pattern,
                                   model=rig.distortion_model).radiance
            if blur_px > 0:
                radiance = cv2.GaussianBlur(radiance, (0, 0), sigmaX=float(blur_px), sigmaY=float(blur_px),
                                            borderType=cv2.BORDER_REFLECT)
            images.append(effects.expose(radiance, cam, rng))
        out.append((images[0], images[1]))
        if progress:
            progress(f"rendered pair {placement.pair} ({n + 1}/{len(placements)})")
    return out
