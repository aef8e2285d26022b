"""Plants, not green things: the automatic plant mask and its plant instances.

:func:`segment_plants` takes the left image and a depth cue registered to it
(a disparity, an organized cloud or a depth map) and returns a
:class:`PlantSegmentation`: the plant mask and the plants in it, numbered left
to right. No colour is assumed: the plants may be green, purple, silver,
yellowing or variegated, and a green watering can, a green box, pots, soil,
trays and stakes are left out. The cues, in order:

1. Shape (:mod:`canopy_stereo.segmentation.shape`): the dominant planes of the
   depth cue (backdrop, wall, table, tray) are background; what stands off them
   is a plant where its depth is rough (thin leaves and stems at many depths) and
   a solid object where it is smooth over a wide window and the smooth region
   stands on the ground (pots, cans, boxes).
2. Colour, learned: colour models of plant and background are fitted to the
   pixels the shape cue is sure of, and a graph cut with those models kept fixed
   decides the rest (the background gaps a matcher fills between leaves, pixels
   without depth, the edges of leaves).
3. Connectedness: plant regions smaller than ``min_region`` are dropped; a
   region that is one straight thin stick (a stake, a wire) is not a plant;
   the remaining regions are grouped into plants (regions whose depths agree
   and which lie close together belong to one plant) and numbered by their
   centroid column (:func:`plant_instances`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.images import to_bgr
from canopy_stereo.segmentation.colour_model import (
    MIN_SAMPLES,
    SURE_LOG_RATIO,
    colour_log_ratio,
    grabcut_with_models,
    relabel_by_colour,
)
from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD, labels_to_mask
from canopy_stereo.segmentation.roots import MIN_ROOT_PIXELS, container_bands, split_by_roots
from canopy_stereo.segmentation.shape import (
    attached_parts,
    caps,
    edge_density,
    fit_ground,
    fit_planes,
    grounded_solids,
    inverse_depth,
    jump_edges,
    local_roughness,
    solids_behind,
    standing_out,
)


@dataclass(frozen=True)
class PlantSegmenterSettings:
    """Options of :func:`segment_plants` (lengths in pixels of the processed image unless said).

    Attributes:
        scale: processing scale in (0, 1] (the image and the depth cue are resampled to
            it; the mask is resized back); None: :func:`processing_scale` of the image
            (half size from 640 pixels wide up, full size at 320: the cues' windows and
            sizes are meant for about 320 pixels across).
        noise: depth-cue noise in inverse-depth units (disparity pixels; for clouds and
            depth maps the median point reads as 50): planes take pixels within 2.5 x,
            rough means a local plane misses by more than 1.5 x.
        window: half-size of the roughness window.
        max_missing: a window with more than this fraction of pixels without depth is rough.
        min_solid: fewest pixels (fraction of the image) of a grounded smooth region
            taken as a solid object.
        min_region: plant regions smaller than this fraction of the image are dropped.
        stick_ratio: a plant region that is a straight stick (a stake) is not a plant: its
            spread (standard deviation) along its main axis is above this multiple of its
            largest inscribed radius and across it below 1.5 times that radius.
        texture: edge density (fraction of Canny edge pixels in the window) above which a
            pixel is textured (foliage), below which it may belong to a plain solid.
        ungrounded_solids: take smooth plain regions for solid objects even when they do not
            stand on the ground plane (for scenes whose table has no depth).
        colour_space: ``"lab"`` or ``"bgr"``: the colours the learned models see.
        cap_fraction: height of the band above a solid (its soil), as a fraction of its width.
        rim_fraction: height of the band just above a solid (its rim) that is background unless
            the shape cue is sure a plant stands out there, as a fraction of its width.
        use_colour: learn colour models from the shape cue and cut with them.
        min_plant: smallest plant, 0..1, as a fraction of the largest plant's foliage area
            (pixels weighted by their squared depth, so near and far plants compare in real
            size; pixel counts with a disparity cue, whose offset is unknown): smaller regions
            are fragments, joined to a plant beside them or left out (:func:`plant_instances`);
            0 keeps every region.
        object_colour: a region touching a solid object whose mean Lab colour lies within this
            distance (CIE76 Delta E, 0..100) of the object's is part of the object (its handle,
            its spout), not a plant; 0 turns the test off. Measured: a watering can's handle
            5.5 from its can; plants 15-36 from their pots (the jade plant's lowest leaves in
            the shade of the Middlebury Plants terracotta pot: 14.8).
    """

    scale: float | None = None
    noise: float = 0.5
    window: int = 4
    max_missing: float = 0.25
    min_solid: float = 0.002
    min_region: float = 0.0005
    stick_ratio: float = 6.0
    texture: float = 0.12
    ungrounded_solids: bool = False
    colour_space: str = "lab"
    cap_fraction: float = 0.15
    rim_fraction: float = 0.06
    use_colour: bool = True
    min_plant: float = 0.1
    object_colour: float = 10.0

    def __post_init__(self):
        if not 0.0 <= float(self.min_plant) <= 1.0:
            raise CanopyStereoError(f"min_plant must be a fraction in [0, 1] of the largest plant, "
                                    f"got {self.min_plant}")
        if not 0.0 <= float(self.object_colour) <= 100.0:
            raise CanopyStereoError(f"object_colour must be a Lab distance in [0, 100], got {self.object_colour}")

    def replace(self, **changes) -> PlantSegmenterSettings:
        return replace(self, **changes)


#: The default settings.
PLANT_SEGMENTER = PlantSegmenterSettings()


@dataclass
class PlantSegmentation:
    """Result of :func:`segment_plants` (all images on the input image's grid).

    Attributes:
        mask: (H, W) uint8, 255 = plant.
        instances: (H, W) int32 plant number, 0 = not plant, 1..N left to right
            (by the column of each plant's pixel centroid).
        plants: per plant ``{"plant_index", "pixels", "bbox": [x, y, w, h], "centroid_px": [u, v]}``.
        cues: diagnostic maps at the processing scale: ``planes`` (bool), ``solids``
            (bool), ``rough`` (bool), ``seed`` (GrabCut labels).
    """

    mask: np.ndarray
    instances: np.ndarray
    plants: list = field(default_factory=list)
    cues: dict = field(default_factory=dict)

    @property
    def n_plants(self) -> int:
        return len(self.plants)


def processing_scale(width: int) -> float:
    """The default processing scale of an image ``width`` pixels wide: about 320 pixels
    across, at least half size, at most full size (0.5 from 640 pixels up, 1.0 at 320)."""
    return float(min(1.0, max(0.5, 320.0 / max(1, int(width)))))


def _resize_map(arr: np.ndarray, size) -> np.ndarray:
    if (arr.shape[1], arr.shape[0]) == tuple(size):
        return arr
    return cv2.resize(arr, size, interpolation=cv2.INTER_NEAREST)


def shape_seed(q: np.ndarray, image_bgr: np.ndarray, *,
               settings: PlantSegmenterSettings = PLANT_SEGMENTER) -> tuple[np.ndarray, dict]:
    """GrabCut labels (uint8 (h, w)) from the inverse-depth map ``q`` and the image's texture,
    and the cue maps.

    Sure background: smooth pixels of the dominant planes, and solid objects (regions
    smooth in depth and plain in texture that stand on the ground) with the parts
    attached to them without a depth jump (handles, spouts, rims); probable background:
    the rest of the planes, pixels without depth and the band above each solid (the soil
    in a pot), whose lowest part (the rim) is sure background where the shape cue is not
    sure a plant stands out; sure plant: textured pixels off the planes away from solids; probable
    plant: other pixels off the planes.
    """
    h, w = q.shape
    valid = np.isfinite(q)
    if valid.sum() < 50:
        raise ImageError("the depth cue has fewer than 50 valid pixels")
    noise = float(settings.noise)
    r = int(settings.window)
    planes = fit_planes(q, tolerance=2.5 * noise, iterations=120)
    qmed = float(np.nanmedian(q))
    if not any(p.is_ground(qmed, h) for p in planes):
        taken = np.zeros((h, w), bool)
        for p in planes:
            taken |= p.inliers
        ground_plane = fit_ground(q, ~taken, tolerance=2.5 * noise)
        if ground_plane is not None:
            planes.append(ground_plane)
    on_plane = np.zeros((h, w), bool)
    lead = np.full((h, w), np.inf)  # how far each pixel stands in front of every plane
    ground = np.zeros((h, w), bool)
    for plane in planes:
        on_plane |= plane.inliers
        lead = np.fmin(lead, plane.residual(q))
        if plane.is_ground(qmed, h):
            ground |= plane.inliers
    rms, missing = local_roughness(q, r)
    rough = (rms > 1.5 * noise) | (missing > settings.max_missing)
    textured = edge_density(image_bgr, r) > settings.texture
    plain = edge_density(image_bgr, 2 * r) < 0.1 * settings.texture  # no edge in a wide window
    edges = jump_edges(q, 4.0 * noise)
    objects = valid & ~on_plane
    smooth = objects & ~rough & ~edges & ~textured
    below = np.zeros((h, w), bool)
    below[:-1] = ground[1:]
    contact = cv2.dilate(below.astype(np.uint8), np.ones((2 * r + 1, 3), np.uint8)).astype(bool)
    contact[h - 1 - r:] = True
    if settings.ungrounded_solids:
        contact[:] = True
    min_solid = max(20, int(settings.min_solid * h * w))
    solids = grounded_solids(smooth, contact, min_pixels=min_solid)
    solids |= solids_behind(smooth, solids, q, min_pixels=min_solid)
    solids = attached_parts(solids, q, objects, jump=3.0 * noise, reach=6 * r)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    solids_grown = cv2.dilate(solids.astype(np.uint8), k).astype(bool) & ~on_plane
    cap = caps(solids, fraction=settings.cap_fraction) & ~solids_grown
    labels = np.full((h, w), GC_PR_BGD, np.uint8)
    labels[objects & ~solids_grown & ~cap & ~plain] = GC_PR_FGD
    evidence = objects & ~solids_grown & ~cap & standing_out(lead, 3.0 * noise)
    labels[evidence & textured & ~edges] = GC_FGD
    labels[on_plane & ~rough & ~cv2.dilate(objects.astype(np.uint8), k).astype(bool)] = GC_BGD
    labels[solids] = GC_BGD
    # the band just above a solid is its rim (the part of a pot the smooth region misses):
    # background, unless the shape cue is sure something stands out there (a stem)
    labels[caps(solids, fraction=settings.rim_fraction) & ~solids_grown & ~evidence] = GC_BGD
    cues = {"planes": on_plane, "ground": ground, "solids": solids_grown, "rough": rough,
            "textured": textured, "plain": plain & ~solids_grown, "caps": cap, "evidence": evidence, "q": q}
    return labels, cues


def segment_plants(image_bgr, *, disparity=None, points=None, depth=None, camera=None,
                   settings: PlantSegmenterSettings = PLANT_SEGMENTER) -> PlantSegmentation:
    """Plant mask and plant instances of an image with a depth cue (see the module docstring).

    Args:
        image_bgr: (H, W, 3) uint8 BGR image (grey is accepted).
        disparity: (H, W) disparity on the image's grid, pixels (high = near; negative or
            non-finite = unknown), e.g. a rectified left image and its ``D.pfm``.
        points: (H, W, 3) organized cloud on the image's grid (world units, NaN = none),
            e.g. ``reconstruct_pair(...).organized`` with the original left image.
        depth: (H, W) depth or distance map (low = near).
        camera: (3, 4) ``P`` of the image's camera, for ``points`` (None: estimated).
        settings: :class:`PlantSegmenterSettings`.

    Exactly one of ``disparity``, ``points``, ``depth`` is needed. Raises
    :class:`ImageError` on bad input; a scene without plants gives an empty mask.
    """
    img = to_bgr(np.asarray(image_bgr), "image")
    h, w = img.shape[:2]
    for name, arr in (("disparity", disparity), ("cloud", points), ("depth", depth)):
        if arr is not None and np.asarray(arr).shape[:2] != (h, w):
            a = np.asarray(arr)
            raise ImageError(f"the {name} is {a.shape[1] if a.ndim > 1 else '?'}x{a.shape[0]} but the "
                             f"image is {w}x{h}; it must be registered to the image")
    scale = processing_scale(w) if settings.scale is None else float(settings.scale)
    if not 0 < scale <= 1:
        raise CanopyStereoError(f"scale must be in (0, 1], got {settings.scale}")
    q_full = inverse_depth(disparity=disparity, points=points, depth=depth, camera=camera)
    size = (max(16, round(w * scale)), max(16, round(h * scale)))
    small = img if size == (w, h) else cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    q = _resize_map(q_full, size)
    if disparity is not None:
        q = q * (size[0] / w)  # disparities shrink with the image
    labels, cues = shape_seed(q, small, settings=settings)
    cues["seed"] = labels
    if settings.use_colour:
        # the cut runs on the full image: crisp leaf edges from cues found at the processing scale
        full_labels = _resize_map(labels, (w, h))
        plain = _resize_map((cues["plain"] & (labels == GC_PR_BGD)).astype(np.uint8), (w, h)) > 0
        colours = cv2.cvtColor(img, cv2.COLOR_BGR2LAB) if settings.colour_space == "lab" else img
        mask = labels_to_mask(_colour_cut(colours, full_labels, plain)) > 0
        near_solid = _resize_map((cues["solids"] | cues["caps"]).astype(np.uint8), (w, h)) > 0
        mask = _with_shape_evidence(mask, _resize_map(cues["evidence"].astype(np.uint8), (w, h)) > 0,
                                    near_solid)
        if settings.object_colour > 0:
            solids = _resize_map(cues["solids"].astype(np.uint8), (w, h)) > 0
            lab_img = colours if settings.colour_space == "lab" else cv2.cvtColor(img, cv2.COLOR_BGR2LAB)
            mask = _without_object_parts(mask, solids, lab_img, max_distance=float(settings.object_colour))
    else:
        mask = labels_to_mask(labels) > 0
        if mask.shape != (h, w):
            mask = cv2.resize(mask.astype(np.uint8) * 255, (w, h), interpolation=cv2.INTER_LINEAR) >= 128
    mask = _drop_small_and_sticks(mask, settings)
    roots = _resize_map(container_bands(cues["solids"], cues["caps"]), (w, h))
    # a disparity's offset (doffs) is unknown here: its regions are weighed by their pixels
    instances, plants = plant_instances(mask, q_full, min_plant=float(settings.min_plant), roots=roots,
                                        depth_weighted=disparity is None)
    return PlantSegmentation(mask=np.where(instances > 0, 255, 0).astype(np.uint8), instances=instances,
                             plants=plants, cues=cues)


def _colour_cut(img: np.ndarray, labels: np.ndarray, plain: np.ndarray) -> np.ndarray:
    """Labels after relabelling by colour models learned from the sure pixels (and, for the
    background, the ``plain`` pixels: walls and objects without texture) and a graph cut."""
    k = np.ones((3, 3), np.uint8)
    plant = cv2.erode((labels == GC_FGD).astype(np.uint8), k, iterations=2).astype(bool)
    background = (labels == GC_BGD) | plain
    if plant.sum() < MIN_SAMPLES or background.sum() < MIN_SAMPLES:
        return labels
    # plant training pixels whose colour the background explains best are the background
    # a matcher spread between leaves: leave them out of the plant's model
    llr, _, background_gmm = colour_log_ratio(img, plant, background)
    cleaner = plant & (llr > 0)
    if cleaner.sum() >= MIN_SAMPLES:
        plant = cleaner
    llr, plant_gmm, background_gmm = colour_log_ratio(img, plant, background, background_gmm=background_gmm)
    relabelled = relabel_by_colour(labels, llr, sure=SURE_LOG_RATIO)
    relabelled[labels == GC_BGD] = GC_BGD  # the shape cue's background stands
    # the cut only where something is in doubt or plant: the box around those pixels, 8 px margin
    vs, us = np.nonzero(relabelled != GC_BGD)
    if not len(vs):
        return relabelled
    y0, y1 = max(0, vs.min() - 8), min(img.shape[0], vs.max() + 9)
    x0, x1 = max(0, us.min() - 8), min(img.shape[1], us.max() + 9)
    relabelled[y0:y1, x0:x1] = grabcut_with_models(img[y0:y1, x0:x1], relabelled[y0:y1, x0:x1],
                                                   plant_gmm, background_gmm)
    return relabelled


def _with_shape_evidence(mask: np.ndarray, sure: np.ndarray, near_solid: np.ndarray) -> np.ndarray:
    """``mask`` without the regions that touch a solid object (or the band above it) and hold
    too few pixels the shape cue is sure stand out of the planes off the solids (fewer than
    30 % of the region): next to an object, colour may extend a plant but not make one (the
    lit top of a green box); elsewhere (seedlings a few millimetres above their tray) it may."""
    n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return mask
    sizes = np.bincount(lab.ravel(), minlength=n)
    evidence = np.bincount(lab[sure & mask], minlength=n)
    touching = np.bincount(lab[near_solid & mask], minlength=n) > 0
    keep = ~touching | (evidence >= 0.3 * sizes)
    keep[0] = False
    return keep[lab]


def _without_object_parts(mask: np.ndarray, solids: np.ndarray, lab_img: np.ndarray, *,
                          max_distance: float) -> np.ndarray:
    """``mask`` without the regions (8-connected) that touch a solid object (within 2 pixels)
    and whose mean colour (uint8 Lab image, OpenCV's scaling: L * 255 / 100, a and b + 128)
    lies within ``max_distance`` (CIE76, L in 0..100) of that object's: the handle of a
    watering can that stands out of the planes like a plant but has the can's colour."""
    n, lab = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    if n <= 1 or not solids.any():
        return mask
    ns, solid_lab = cv2.connectedComponents(solids.astype(np.uint8), connectivity=8)
    colours = lab_img.reshape(-1, 3).astype(np.float64) * np.array([100.0 / 255.0, 1.0, 1.0])
    mean, smean = _label_means(lab, n, colours), _label_means(solid_lab, ns, colours)
    near = cv2.dilate(solid_lab.astype(np.float32), np.ones((5, 5), np.uint8)).astype(np.int64)
    keep = np.ones(n, bool)
    keep[0] = False
    sel = (lab > 0) & (near > 0)
    pairs, hits = np.unique(lab[sel] * ns + near[sel], return_counts=True)
    regions, objects = pairs // ns, pairs % ns
    for i in np.unique(regions):  # each region against the object it touches most
        s = objects[regions == i][np.argmax(hits[regions == i])]
        keep[i] = np.linalg.norm(mean[i] - smean[s]) > max_distance
    return keep[lab]


def _label_means(lab: np.ndarray, n: int, values: np.ndarray) -> np.ndarray:
    """(n, C) float64 mean of ``values`` ((H * W, C)) over each label 0..n-1 of ``lab``."""
    flat = lab.ravel()
    counts = np.maximum(np.bincount(flat, minlength=n), 1).astype(np.float64)
    sums = np.stack([np.bincount(flat, weights=values[:, c], minlength=n) for c in range(values.shape[1])], 1)
    return np.asarray(sums, np.float64) / counts[:, None]


def _drop_small_and_sticks(mask: np.ndarray, settings: PlantSegmenterSettings) -> np.ndarray:
    """``mask`` without regions below ``min_region`` of the image and without sticks."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    min_px = max(1, int(settings.min_region * mask.size))
    dist = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] < min_px:
            continue
        vs, us = np.nonzero(lab == i)
        pts = np.stack([us, vs], 1).astype(np.float64)
        cov = np.cov((pts - pts.mean(0)).T)
        minor, major = np.sqrt(np.clip(np.linalg.eigvalsh(cov), 0.0, None))
        radius = max(1.0, float(dist[vs, us].max()))
        keep[i] = not (major > settings.stick_ratio * radius and minor < 1.5 * radius)
    return keep[lab]


def _region_medians(lab: np.ndarray, n: int, q: np.ndarray | None) -> np.ndarray:
    """(n,) median of the finite ``q`` of each label 1..n-1 of ``lab`` (NaN: none or no ``q``)."""
    qs = np.full(n, np.nan)
    if q is None:
        return qs
    ok = (lab > 0) & np.isfinite(q)
    labels, values = lab[ok], np.asarray(q, np.float64)[ok]
    order = np.lexsort((values, labels))
    labels, values = labels[order], values[order]
    starts = np.searchsorted(labels, np.arange(n))
    stops = np.searchsorted(labels, np.arange(n), side="right")
    for i in range(1, n):
        a, b = starts[i], stops[i]
        if b > a:
            mid = (a + b - 1) / 2.0
            qs[i] = 0.5 * (values[int(np.floor(mid))] + values[int(np.ceil(mid))])
    return qs


#: Default smallest plant, as a fraction of the largest plant's foliage area (see :func:`plant_instances`).
MIN_PLANT_FRACTION = 0.1


def _foliage_areas(lab: np.ndarray, n: int, q: np.ndarray | None, qs: np.ndarray) -> np.ndarray:
    """(n,) foliage area of each label 1..n-1 of ``lab`` up to one common factor: the sum over its
    pixels of ``1 / q^2`` (a pixel's area on the object grows with the square of its depth;
    pixels without ``q`` count at their region's median ``q``), or its pixel count without ``q``."""
    if q is None or not np.isfinite(qs[1:]).any():
        return np.bincount(lab.ravel(), minlength=n).astype(np.float64)
    fill = np.where(np.isfinite(qs), qs, np.nanmedian(qs[1:]))
    qq = np.where(np.isfinite(q) & (q > 0), q, fill[lab])
    return np.bincount(lab.ravel(), weights=(1.0 / qq ** 2).ravel(), minlength=n)


def _split_rooted(lab, n, stats, q, roots):
    """Connected regions (``lab`` 1..n-1) standing in two or more containers' bands split into
    their plants (:func:`~canopy_stereo.segmentation.roots.split_by_roots`): ``(n, lab, stats,
    origin)`` with the new labels, their ``cv2`` stats and the region each comes from."""
    sel = (lab > 0) & (roots > 0)
    nroot = int(roots.max()) + 1
    hits = np.bincount(lab[sel] * nroot + roots[sel], minlength=n * nroot).reshape(n, nroot)
    candidates = np.nonzero((hits >= MIN_ROOT_PIXELS).sum(axis=1) >= 2)[0]
    origin = list(range(n))
    if not len(candidates):
        return n, lab, stats, np.arange(n)
    lab = lab.copy()
    for i in candidates:
        pieces = split_by_roots(lab == i, q, roots)
        for piece in (pieces or [])[1:]:
            lab[piece] = len(origin)
            origin.append(int(i))
    n = len(origin)
    stats = np.zeros((n, 5), np.int64)
    from scipy import ndimage

    for k, box in enumerate(ndimage.find_objects(lab), start=1):
        if box is not None:
            sv, su = box
            stats[k, :4] = su.start, sv.start, su.stop - su.start, sv.stop - sv.start
    return n, lab, stats, np.asarray(origin)


def plant_instances(mask: np.ndarray, q: np.ndarray | None = None, *, join_px: int | None = None,
                    min_plant: float = MIN_PLANT_FRACTION, roots: np.ndarray | None = None,
                    depth_weighted: bool = True):
    """Plants of a mask: ``(instances (H, W) int32, plants list)``.

    Connected regions are one plant each, except that:

    * with ``roots`` ((H, W) int, the band above each container numbered 1..:
      :func:`~canopy_stereo.segmentation.roots.container_bands`) and ``q``, a region that stands
      in the bands of two or more containers is split into one plant per container along its
      depth jumps (two potted plants whose leaves overlap in the image:
      :func:`~canopy_stereo.segmentation.roots.split_by_roots`);

    * a region whose foliage area (its pixels weighted by the square of their depth, from the
      inverse depth ``q``; pixel counts without ``q`` or with ``depth_weighted=False``, e.g. for a
      disparity whose offset ``doffs`` is unknown) is below ``min_plant`` (0..1) times the
      largest region's is a *fragment*: it joins the nearest region within ``join_px`` pixels
      (default 2 % of the image diagonal) whose median inverse depth agrees within 15 % (a
      leaf of a plant seen apart); a fragment nothing takes (alone or with other fragments,
      still below ``min_plant``) is not a plant (a piece of a table edge) and is left out;
    * two plant-sized regions join only when they come within a quarter of ``join_px`` (at
      least 3 pixels) of each other with agreeing depths (one plant that the mask broke): the
      seedlings of a tray, a few millimetres apart, stay apart.

    Plants are numbered 1.. by the column of their pixel centroid (ties: by row).
    """
    m = np.asarray(mask) > 0
    h, w = m.shape
    if join_px is None:
        join_px = max(2, int(0.02 * np.hypot(h, w)))
    if not 0.0 <= float(min_plant) <= 1.0:
        raise CanopyStereoError(f"min_plant must be a fraction in [0, 1] of the largest plant, got {min_plant}")
    close_px = max(3, join_px // 4)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    origin = np.arange(n)  # the connected region each label comes from
    if roots is not None and q is not None and n > 1:
        n, lab, stats, origin = _split_rooted(lab, n, stats, q, np.asarray(roots))
    parent = list(range(n))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    qs = _region_medians(lab, n, q)
    area = _foliage_areas(lab, n, q if depth_weighted else None, qs)
    big = area >= float(min_plant) * (area[1:].max() if n > 1 else 0.0)
    big[0] = False
    group_area = area.copy()
    if n > 2:
        k_far = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * join_px + 1, 2 * join_px + 1))
        k_close = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * close_px + 1, 2 * close_px + 1))
        links = []  # (gap class, i, j): close links first, then fragments by size
        for i in range(1, n):
            # the region grown by join_px, within its box widened by join_px (the same pixels
            # as growing it on the whole image)
            x, y, bw, bh = (int(v) for v in stats[i, :4])
            x0, y0 = max(0, x - join_px), max(0, y - join_px)
            x1, y1 = min(w, x + bw + join_px), min(h, y + bh + join_px)
            crop = lab[y0:y1, x0:x1]
            own = (crop == i).astype(np.uint8)
            on = m[y0:y1, x0:x1]
            near = set(np.unique(crop[(cv2.dilate(own, k_close) > 0) & on]).tolist())
            for j in np.unique(crop[(cv2.dilate(own, k_far) > 0) & on]).tolist():
                if j <= i:
                    continue
                same_depth = (not np.isfinite(qs[i]) or not np.isfinite(qs[j])
                              or abs(qs[i] - qs[j]) <= 0.15 * max(qs[i], qs[j]))
                if origin[i] == origin[j]:
                    continue  # one region split between the containers its plants grow from
                if same_depth and (j in near or not (big[i] and big[j])):
                    links.append((j not in near, i, j))
        for far, i, j in sorted(links):
            a, b = find(i), find(j)
            if a == b or (far and big[a] and big[b]):
                continue
            parent[b] = a
            big[a] |= big[b]
            group_area[a] += group_area[b]
    roots = np.array([find(i) for i in range(n)])
    groups = np.unique(roots[1:]) if n > 1 else np.zeros(0, np.int64)
    if len(groups):  # fragments nothing took are not plants
        groups = groups[group_area[groups] >= float(min_plant) * group_area[groups].max()]
        roots = np.where(np.isin(roots, groups), roots, 0)
    plants: list[dict] = []
    inst = np.zeros((h, w), np.int32)
    if not len(groups):
        return inst, plants
    compact = np.zeros(n, np.int64)
    compact[groups] = np.arange(1, len(groups) + 1)
    g = compact[roots][lab]  # 0 = not plant, 1..G in the order of ``groups``
    vs, us = np.mgrid[0:h, 0:w]
    counts = np.bincount(g.ravel(), minlength=len(groups) + 1)
    cus = np.bincount(g.ravel(), weights=us.ravel(), minlength=len(groups) + 1) / np.maximum(counts, 1)
    cvs = np.bincount(g.ravel(), weights=vs.ravel(), minlength=len(groups) + 1) / np.maximum(counts, 1)
    order = sorted(range(1, len(groups) + 1), key=lambda t: (cus[t], cvs[t]))
    renumber = np.zeros(len(groups) + 1, np.int32)
    renumber[order] = np.arange(1, len(order) + 1)
    inst = renumber[g]
    from scipy import ndimage

    boxes = ndimage.find_objects(g)
    for k_, t in enumerate(order, start=1):
        sv, su = boxes[t - 1]
        plants.append({"plant_index": k_, "pixels": int(counts[t]),
                       "bbox": [int(su.start), int(sv.start), int(su.stop - su.start), int(sv.stop - sv.start)],
                       "centroid_px": [float(cus[t]), float(cvs[t])]})
    return inst, plants
