"""Size of one leaf from its mask on the left image and the organized cloud.

Steps (all lengths in world units, areas in world units squared):

1. The leaf's points are cleaned (pieces cut off by depth jumps and points
   far off a smooth fit, such as background depths bled onto the leaf's rim
   by the matcher, are dropped) and a smooth surface is fitted over the whole
   mask and a 3-pixel rim around it (:mod:`canopy_stereo.measure.surface`),
   which also fills holes in the reconstruction. For a reconstruction, with
   the camera known, the surface is a low-order inverse depth along the
   camera's rays, fitted robustly over the whole leaf (stereo errs along the
   rays; a plane is exact); a noise-free (rendered) cloud is used as it is.
2. Area: the sum over the leaf's pixels of their surface element
   ``|X_u x X_v|``, i.e. the one-sided area of the triangulated grid surface
   split into the dual cells of its vertices.
3. Plane: least-squares plane of the surface points weighted by area; its
   normal faces the camera.
4. Ends (tip and base): the two pixels farthest apart along the surface
   (geodesic diameter on the grid), or the two outline points farthest apart
   in 3D, whichever gives the longer length.
5. Length: the surface curve from outline to outline in the plane through the
   two ends and the leaf normal (the midrib of a leaf bent or folded about it).
6. Width: the longest surface curve across the midrib, cut by planes normal to
   the midrib at stations along it, refined around the widest station.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.clouds import check_cloud, check_on_grid
from canopy_stereo.measure.geodesic import geodesic_diameter
from canopy_stereo.measure.instances import largest_surface_part
from canopy_stereo.measure.sections import Section, measure_section, outline_field
from canopy_stereo.measure.surface import (
    EXACT_ROUGHNESS,
    GridSurface,
    fit_grid_surface,
    fit_ray_surface,
    local_linear_fit,
    roughness,
    shift_projection,
)

#: Pixels of extrapolated surface around a leaf mask (room for the outline).
RIM_PX = 3
#: Leaves seen more obliquely than this (degrees) are not ``reliable``.
RELIABLE_VIEW_ANGLE_DEG = 75.0
#: A leaf whose length section is shorter than this fraction of the longest
#: path over its surface is not leaf-shaped (bent, or several leaves) and not ``reliable``.
MIN_SECTION_FRACTION = 0.8
#: A candidate length section shorter than this fraction of the straight distance between its
#: two ends left the region near its middle (an L-shaped cluster of leaves, not one leaf): it is
#: not taken (its length, a few millimetres, changed wildly with the cloud's last digits).
MIN_SECTION_OF_CHORD = 0.5
#: View angle (degrees) beyond which a pixel's surface area is capped.
MAX_VIEW_ANGLE_DEG = 84.0
#: Width stations along the midrib before refinement.
WIDTH_STATIONS = 41
#: Stations on each side of the widest one used to fit the width profile.
WIDTH_WINDOW = 5


@dataclass
class LeafMeasurement:
    """Measured size of one leaf.

    Attributes:
        id: the leaf's label.
        length: surface length of the midrib section, outline to outline.
        width: longest surface section across the midrib.
        area: one-sided surface area.
        normal: (3,) unit normal of the fitted plane, facing the camera.
        centroid: (3,) area-weighted centre of the leaf surface.
        chord: straight distance between the two ends of the length.
        ends: (2, 3) the ends of the length curve (tip/base, order arbitrary).
        width_ends: (2, 3) the ends of the widest cross section.
        plane_rms: RMS distance of the surface from the fitted plane (flatness).
        n_pixels: pixels in the leaf mask.
        n_points: pixels of the mask with a usable 3D point.
        complete: False when the length or width curve ran off the surface
            before reaching the outline (leaf cut by the image border or a hole).
        touches_border: the mask touches the image border (leaf may be cut off).
        surface_points: (n, 3) points of the fitted leaf surface at the leaf's
            pixels (not in the report; used for canopy extents).
        inlier_points: (m, 3) the leaf's own points that the surface fit kept.
        outlier_mask: (H, W) bool, the leaf's pixels whose points the surface
            fit rejected (matching errors: not used for canopy extents either).
        extra: further report fields: ``surface_model``, ``outliers`` (points
            dropped), ``view_angle_deg`` (between the normal and the line of
            sight; above about 70 degrees a leaf is seen nearly edge-on and its
            sizes are unreliable), ``grazing_fraction`` (pixels seen at more
            than :data:`MAX_VIEW_ANGLE_DEG`, whose area is capped), ``reliable``
            (complete, not cut by the image border, seen less obliquely than
            :data:`RELIABLE_VIEW_ANGLE_DEG`, with under 20 % grazing pixels and
            a length of at least :data:`MIN_SECTION_FRACTION` of
            ``geodesic_length``, the longest shortest path over the surface
            (grid Dijkstra, up to 3 % long)).
    """

    id: int
    length: float
    width: float
    area: float
    normal: np.ndarray
    centroid: np.ndarray
    chord: float
    ends: np.ndarray
    width_ends: np.ndarray
    plane_rms: float
    n_pixels: int
    n_points: int
    complete: bool
    touches_border: bool
    surface_points: np.ndarray | None = None
    inlier_points: np.ndarray | None = None
    outlier_mask: np.ndarray | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Plain-Python form used in REPORT.json."""
        def r(x):
            return [round(float(v), 6) for v in np.ravel(x)]

        return {
            "id": int(self.id),
            "length": round(float(self.length), 6),
            "width": round(float(self.width), 6),
            "area": round(float(self.area), 6),
            "normal": r(self.normal),
            "centroid": r(self.centroid),
            "chord": round(float(self.chord), 6),
            "ends": [r(p) for p in self.ends],
            "width_ends": [r(p) for p in self.width_ends],
            "plane_rms": round(float(self.plane_rms), 6),
            "n_pixels": int(self.n_pixels),
            "n_points": int(self.n_points),
            "complete": bool(self.complete),
            "touches_border": bool(self.touches_border),
            **self.extra,
        }


def robust_inliers(organized: np.ndarray, valid: np.ndarray, *, sigma: float = 6.0,
                   floor: float | None = None, iterations: int = 2) -> np.ndarray:
    """Drop points far from a smooth fit of their neighbours.

    A point is an outlier when its distance along the local normal from the
    local-linear fit of the other points (scale ``sigma`` pixels) exceeds
    ``max(4 * 1.4826 * MAD, floor)``; ``floor`` defaults to two pixel sizes
    (square root of the median pixel footprint). Returns the inlier mask.
    """
    keep = valid.copy()
    for _ in range(iterations):
        if keep.sum() < 8:
            break
        X, Xu, Xv = local_linear_fit(organized, keep, valid, sigma=sigma)
        n = np.cross(Xu, Xv)
        foot = np.linalg.norm(n, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            res = np.abs(np.einsum("hwk,hwk->hw", organized - X, n / foot[..., None]))
        r = res[valid & np.isfinite(res)]
        if not len(r):
            break
        pix = float(np.sqrt(np.nanmedian(foot[valid]))) if floor is None else float(floor)
        thr = max(4.0 * 1.4826 * float(np.median(r[np.isfinite(r)])), 2.0 * pix)
        new = valid & np.isfinite(res) & (res <= thr)
        if np.array_equal(new, keep):
            break
        keep = new
    return keep


def _fit_plane(points: np.ndarray, weights: np.ndarray):
    w = weights / weights.sum()
    c = w @ points
    d = points - c
    cov = (d * w[:, None]).T @ d
    evals, evecs = np.linalg.eigh(cov)
    return c, evecs[:, 0], float(np.sqrt(max(evals[0], 0.0)))


def _width_at(surface, phi, midrib: Section, a: float, normal: np.ndarray):
    station = midrib.point(a)[0]
    t = midrib.tangent(a)[0]
    across = np.cross(normal, t)
    return measure_section(surface, phi, station, t, normal, start=0.0, along_hint=across)


#: Surface models of :func:`measure_leaf`.
SURFACE_MODELS = ("auto", "rays", "local", "exact")
#: The "local" model widens its smoothing to ``roughness / LOCAL_NOISE_TARGET`` pixels ...
LOCAL_NOISE_TARGET = 0.03
#: ... up to this scale.
MAX_LOCAL_SIGMA_PX = 16.0


def measure_leaf(organized: np.ndarray, leaf_mask: np.ndarray, *, leaf_id: int = 1, camera=None,
                 model: str = "auto", degree: int = 2, smoothing_px: float = 2.0,
                 viewpoint=None, min_points: int = 3) -> LeafMeasurement:
    """Measure one leaf.

    Args:
        organized: (H, W, 3) organized cloud on the left image grid (world units,
            NaN = no point).
        leaf_mask: (H, W) bool (or nonzero) mask of the leaf on the same grid.
        leaf_id: label stored in the result.
        camera: (3, 4) left camera ``P`` of the grid, if known (see
            :func:`~canopy_stereo.measure.viewpoint.estimate_camera`).
        model: surface model of the leaf:
            ``"rays"`` (needs ``camera``): inverse depth along the camera's rays
            as a polynomial of ``degree`` in the pixel coordinates, fitted
            robustly; averages the matching errors of a reconstruction over
            the whole leaf (recommended for reconstructions);
            ``"local"``: Gaussian-weighted local-linear fit at ``smoothing_px``
            pixels, widened for rough (noisy) clouds up to 16 pixels;
            ``"exact"``: the points as they are (rendered, noise-free clouds);
            ``"auto"``: ``"exact"`` for noise-free clouds (see :func:`roughness`),
            else ``"rays"`` when the camera is known, else ``"local"``.
        degree: polynomial degree of the ``"rays"`` model (2 suits leaves).
        smoothing_px: Gaussian scale (pixels) of the ``"local"`` model.
        viewpoint: optional (3,) camera centre the normal is turned towards
            (default: the camera's centre, else the camera implied by the grid).
        min_points: fewest 3D points a leaf needs.

    Raises:
        CanopyStereoError: mask of the wrong size, empty, or with fewer than
            ``min_points`` 3D points; unknown model; ``"rays"`` without camera.
    """
    organized = check_cloud(organized)
    mask = np.asarray(leaf_mask).astype(bool)
    check_on_grid(mask, organized, f"leaf {leaf_id}: mask")
    if model not in SURFACE_MODELS:
        raise CanopyStereoError(f"unknown surface model {model!r}; choose one of {', '.join(SURFACE_MODELS)}")
    if model == "rays" and camera is None:
        raise CanopyStereoError("the 'rays' surface model needs the camera (P_left) of the cloud")
    n_pixels = int(mask.sum())
    if n_pixels == 0:
        raise CanopyStereoError(f"leaf {leaf_id}: the mask is empty")
    finite = np.all(np.isfinite(organized), axis=-1)
    valid = mask & finite
    n_valid = int(valid.sum())
    if n_valid < max(3, min_points):
        raise CanopyStereoError(
            f"leaf {leaf_id}: only {n_valid} of its {n_pixels} pixels have a 3D point "
            f"(need at least {max(3, min_points)})")
    H, W = mask.shape
    touches = bool(mask[0].any() or mask[-1].any() or mask[:, 0].any() or mask[:, -1].any())

    # crop around the leaf for speed
    vs, us = np.nonzero(mask)
    margin = RIM_PX + int(np.ceil(12 * max(smoothing_px, 2.0))) + 2
    v0, v1 = max(vs.min() - margin, 0), min(vs.max() + margin + 1, H)
    u0, u1 = max(us.min() - margin, 0), min(us.max() + margin + 1, W)
    crop = (slice(v0, v1), slice(u0, u1))
    pts, m, val = organized[crop], mask[crop], valid[crop]
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * RIM_PX + 1, 2 * RIM_PX + 1))
    domain = cv2.dilate(m.astype(np.uint8), kernel).astype(bool)
    if camera is not None:
        camera = np.asarray(camera, np.float64)
        if viewpoint is None:
            from canopy_stereo.geometry.camera import camera_centre

            viewpoint = camera_centre(camera)

    # pieces cut off by depth jumps (background bled onto the rim) are not leaf
    val_all = val
    val = largest_surface_part(pts, val) if n_valid >= 16 else val
    used = model
    rough = roughness(pts, val) if n_valid >= 16 and model in ("auto", "local") else float("nan")
    if model == "auto":
        used = "exact" if rough < EXACT_ROUGHNESS else ("rays" if camera is not None else "local")
    if used == "rays":
        surface, inl = fit_ray_surface(pts, val, domain, shift_projection(camera, v0, u0), degree=degree)
    elif used == "local":
        # noisier clouds need wider smoothing, else noise adds area and length
        sigma = smoothing_px
        if np.isfinite(rough):
            sigma = float(np.clip(rough / LOCAL_NOISE_TARGET, smoothing_px, MAX_LOCAL_SIGMA_PX))
        inl = robust_inliers(pts, val, sigma=max(sigma, 4.0), iterations=3) if n_valid >= 16 else val
        surface = fit_grid_surface(pts, inl, domain, sigma=sigma)
    else:
        # exact points on the leaf; the rim and holes from a light fit
        inl = robust_inliers(pts, val, sigma=4.0) if n_valid >= 16 else val
        surface = fit_grid_surface(pts, inl, domain, sigma=1.0)
        _merge_exact(surface, fit_grid_surface(pts, inl, domain, sigma=0.0))
    # express everything on the crop of the surface
    sv0, su0 = surface.origin
    sh, sw = surface.domain.shape
    m_s = m[sv0:sv0 + sh, su0:su0 + sw]
    inside = m_s & surface.domain
    if inside.sum() < 3:
        raise CanopyStereoError(f"leaf {leaf_id}: too few usable 3D points to fit its surface")
    phi = outline_field(m_s)
    foot = surface.footprint[inside]
    P = surface.X[inside]
    grazing = 0.0
    if viewpoint is not None:
        # a pixel's area grows as 1 / cos(view angle); beyond MAX_VIEW_ANGLE_DEG
        # (a leaf seen edge-on) it is unmeasurable: cap it there and say how much
        rays = P - np.asarray(viewpoint, np.float64).reshape(3)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        cos = np.abs(np.einsum("nk,nk->n", rays, surface.normals[inside]))
        cap = np.cos(np.deg2rad(MAX_VIEW_ANGLE_DEG))
        grazing = float(np.mean(cos < cap))
        foot = np.where(cos < cap, foot * cos / cap, foot)
    area = float(np.sum(foot))
    centroid, normal, plane_rms = _fit_plane(P, foot)
    facing = np.nanmean(surface.normals[inside], axis=0)
    if viewpoint is not None:
        facing = np.asarray(viewpoint, np.float64).reshape(3) - centroid
    if normal @ facing < 0:
        normal = -normal
    view_angle = float("nan")
    if viewpoint is not None:
        view_angle = float(np.degrees(np.arccos(np.clip(normal @ facing / np.linalg.norm(facing), -1, 1))))

    midrib = None
    end_a = end_b = centroid
    candidates = _candidate_ends(surface.X, inside)
    geodesic = candidates[0][2]
    for cand_a, cand_b, _ in candidates:
        sec = _midrib_section(surface, phi, cand_a, cand_b, normal)
        if sec is not None and sec.length < MIN_SECTION_OF_CHORD * np.linalg.norm(cand_b - cand_a):
            sec = None  # the section left the region near its middle: not one leaf's midrib
        if sec is not None and (midrib is None or sec.length > midrib.length):
            midrib, end_a, end_b = sec, cand_a, cand_b
        elif midrib is None and np.linalg.norm(cand_b - cand_a) > np.linalg.norm(end_b - end_a):
            end_a, end_b = cand_a, cand_b
    chord_dir = end_b - end_a
    complete = True
    if midrib is None:
        # a single pixel row or a degenerate leaf: fall back to the straight chord
        length = chord = float(np.linalg.norm(chord_dir))
        ends = np.stack([end_a, end_b])
        width, width_ends = 0.0, np.stack([centroid, centroid])
        complete = False
    else:
        length, ends, chord = midrib.length, midrib.ends, midrib.chord
        complete &= midrib.complete
        width, width_ends, wcomplete = _leaf_width(surface, phi, midrib, normal)
        complete &= wcomplete
    outliers = int(np.sum(val_all & ~inl))
    outlier_mask = np.zeros((H, W), bool)
    outlier_mask[crop] = val_all & m & ~inl
    return LeafMeasurement(
        id=int(leaf_id), length=float(length), width=float(width), area=area, normal=normal,
        centroid=centroid, chord=float(chord), ends=np.asarray(ends), width_ends=np.asarray(width_ends),
        plane_rms=plane_rms, n_pixels=n_pixels, n_points=n_valid, complete=bool(complete),
        touches_border=touches, surface_points=P, inlier_points=pts[inl & m], outlier_mask=outlier_mask,
        extra={"surface_model": used, "outliers": outliers,
               "view_angle_deg": None if not np.isfinite(view_angle) else round(view_angle, 3),
               "grazing_fraction": round(grazing, 4),
               "geodesic_length": round(float(geodesic), 6),
               "reliable": bool(complete and not touches and grazing < 0.2
                                and length >= MIN_SECTION_FRACTION * geodesic
                                and not (np.isfinite(view_angle) and view_angle > RELIABLE_VIEW_ANGLE_DEG))})


def _candidate_ends(X: np.ndarray, inside: np.ndarray):
    """Candidate ``(tip, base, geodesic distance or NaN)``: the geodesic diameter
    over the grid and, when it lies along another axis (over 20 degrees apart), the farthest
    pair of outline points in 3D (robust where a noisy surface lengthens paths
    across the leaf more than along it)."""
    (va, ua), (vb, ub), geo = geodesic_diameter(X, inside)
    pairs = [(X[va, ua], X[vb, ub], geo)]
    rim = inside & ~cv2.erode(inside.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    P = X[rim]
    if len(P) > 1500:
        P = P[np.linspace(0, len(P) - 1, 1500).astype(int)]
    if len(P) >= 2:
        d2 = np.sum((P[:, None, :] - P[None, :, :]) ** 2, axis=-1)
        i, j = np.unravel_index(int(np.argmax(d2)), d2.shape)
        g = pairs[0][1] - pairs[0][0]
        e = P[j] - P[i]
        cos = abs(g @ e) / max(np.linalg.norm(g) * np.linalg.norm(e), 1e-300)
        if cos < np.cos(np.deg2rad(20.0)):  # a different axis, not the same one twice
            pairs.append((P[i], P[j], float("nan")))
    return pairs


def _midrib_section(surface, phi, end_a, end_b, normal) -> Section | None:
    """Section in the plane through both ends and the leaf normal."""
    chord = end_b - end_a
    norm = float(np.linalg.norm(chord))
    if norm == 0:
        return None
    plane_n = np.cross(chord, normal)
    if np.linalg.norm(plane_n) <= 1e-9 * norm:
        return None
    return measure_section(surface, phi, end_a, plane_n, normal, start=0.5 * norm, along_hint=chord)


def _merge_exact(surface: GridSurface, exact: GridSurface) -> None:
    """Use the exact points (and differences) where they exist on ``surface``'s crop."""
    ev0, eu0 = exact.origin
    sv0, su0 = surface.origin
    eh, ew = exact.domain.shape
    dv, du = ev0 - sv0, eu0 - su0
    sl = (slice(dv, dv + eh), slice(du, du + ew))
    ok = exact.domain & np.all(np.isfinite(exact.X_u), -1) & np.all(np.isfinite(exact.X_v), -1)
    for name in ("X", "X_u", "X_v"):
        dst = getattr(surface, name)[sl]
        dst[ok] = getattr(exact, name)[ok]
    surface.domain[sl] |= ok


def _leaf_width(surface, phi, midrib: Section, normal):
    """Widest cross section: sections at stations along the midrib; a parabola
    through the widths around the widest station gives the maximum (less
    sensitive to the pixel steps of the outline than the largest single value)."""
    a0, a1 = midrib.a_range
    span = a1 - a0
    stations = a0 + span * np.linspace(0.04, 0.96, WIDTH_STATIONS)
    sections = [_width_at(surface, phi, midrib, a, normal) for a in stations]
    widths = np.array([s.length if s is not None else np.nan for s in sections])
    if not np.any(np.isfinite(widths)):
        return 0.0, np.stack([midrib.point(0.5 * (a0 + a1))[0]] * 2), False
    k = int(np.nanargmax(widths))
    lo, hi = max(k - WIDTH_WINDOW, 0), min(k + WIDTH_WINDOW + 1, len(stations))
    a, w = stations[lo:hi], widths[lo:hi]
    ok = np.isfinite(w)
    width, a_best = float(widths[k]), float(stations[k])
    if ok.sum() >= 5:
        x = (a[ok] - stations[k]) / span
        c2, c1, c0 = np.polyfit(x, w[ok], 2)
        if c2 < 0:
            xm = float(np.clip(-c1 / (2 * c2), x.min(), x.max()))
            width = float(c0 + c1 * xm + c2 * xm * xm)
            a_best = float(stations[k] + xm * span)
    best = _width_at(surface, phi, midrib, a_best, normal) or sections[k]
    return width, best.ends, bool(best.complete)
