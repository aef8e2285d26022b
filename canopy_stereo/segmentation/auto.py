"""Automatic plant mask: colour and depth cues seed GrabCut, no interaction.

Each cue votes per pixel on a four-level scale, the GrabCut labels: sure
background, probable background, probable plant, sure plant. A cue is split
in two classes by Otsu's threshold; values beyond the midpoint between the
threshold and a class mean are "sure", the others "probable".

* Colour: a vegetation index on normalised chromaticity (ExG, or ExG - ExR),
  high = plant. Good for green plants on soil, a bench or a grey backdrop.
* Depth: a disparity map (high = near) or a depth map (low = near) registered
  to the image; near = plant. Good whenever the plant stands in front of its
  background, whatever its colour.

With both cues, the colour threshold is found among the near pixels only, so
it separates the plant from what stands beside it at the same distance (a
pot, soil), and a pixel is sure plant only when both cues agree; far pixels
are sure background. The seed is then refined by GrabCut, and regions smaller
than ``min_region`` pixels are dropped.

Non-green plants (croton's red and yellow leaves, autumn foliage), or green
plants before green foliage: use the depth cue without an index
(``index="none"``) or a rectangle (:func:`grabcut_rect`). With
``index="none"`` a pot at the plant's distance stays in the mask, so draw a
rectangle that leaves it out, or cut it with a depth range.

Without an index the colour cue is learned instead (``colour_model``, on by
default there; :mod:`canopy_stereo.segmentation.colour_model`): colour models
of plant and background are fitted to the pixels the depth cue is sure of
(near and away from depth edges; far), and their log likelihood ratio
relabels the seed: it removes the background gaps between leaves that a
window matcher fills with the leaves' disparity, and decides the pixels
without depth (occlusions, the image border the other camera does not see).
GrabCut then cuts once with those models kept fixed.
"""
from __future__ import annotations

import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.images import to_bgr
from canopy_stereo.segmentation.cleaning import clean_mask_regions
from canopy_stereo.segmentation.colour_model import (
    MIN_SAMPLES,
    SURE_LOG_RATIO,
    colour_log_ratio,
    grabcut_with_models,
    relabel_by_colour,
)
from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD, grabcut_labels
from canopy_stereo.segmentation.indices import INDICES, class_means, otsu_threshold, vegetation_index

#: Vote values of a cue.
SURE_BG, PROB_BG, PROB_FG, SURE_FG = -2, -1, 1, 2
#: Margin (pixels) by which the sure-plant pixels of the depth seed are eroded
#: before a colour model is learned from them.
TRAIN_MARGIN_PX = 2


def otsu_votes(values: np.ndarray, valid: np.ndarray | None = None, within: np.ndarray | None = None):
    """Four-level votes (int8, 0 where not ``valid``) of values split by Otsu's threshold.

    The threshold and class means are computed over ``valid & within``
    (default: all finite values); votes are given on all valid pixels.
    Returns ``(votes, threshold, effectiveness)``, the last being Otsu's
    between-class / total variance ratio (0..1, higher = cleaner split).
    """
    v = np.asarray(values, np.float64)
    ok = np.isfinite(v) if valid is None else (valid & np.isfinite(v))
    sel = ok if within is None else (ok & within)
    if sel.sum() < 2:
        raise ImageError("too few valid pixels for an automatic threshold")
    t = otsu_threshold(v[sel])
    m0, m1 = class_means(v[sel], t)
    vs = np.clip(v[sel], *np.percentile(v[sel], [0.5, 99.5]))
    total = float(np.var(vs))
    frac = float(np.mean(vs > t))
    eff = (frac * (1 - frac) * (m1 - m0) ** 2 / total) if total > 0 else 0.0
    votes = _votes(v, ok, t, 0.5 * (t + m0), 0.5 * (t + m1))
    return votes, t, eff


def range_votes(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Votes for a plant range ``[lo, hi]``: inside = plant (sure beyond 10 % of the
    range from its ends), outside = background (sure beyond 10 % outside)."""
    if not hi > lo:
        raise ImageError(f"range must have hi > lo, got [{lo}, {hi}]")
    v = np.asarray(values, np.float64)
    ok = np.isfinite(v)
    m = 0.1 * (hi - lo)
    votes = np.zeros(v.shape, np.int8)
    inside = ok & (v >= lo) & (v <= hi)
    votes[inside] = PROB_FG
    votes[ok & (v >= lo + m) & (v <= hi - m)] = SURE_FG
    votes[ok & ~inside] = PROB_BG
    votes[ok & ((v < lo - m) | (v > hi + m))] = SURE_BG
    return votes


def _votes(v, ok, t, lo_mid, hi_mid):
    votes = np.zeros(v.shape, np.int8)
    with np.errstate(invalid="ignore"):
        votes[ok & (v > t)] = PROB_FG
        votes[ok & (v > hi_mid)] = SURE_FG
        votes[ok & (v <= t)] = PROB_BG
        votes[ok & (v <= lo_mid)] = SURE_BG
    return votes


def combine_votes(colour: np.ndarray | None, depth: np.ndarray | None) -> np.ndarray:
    """GrabCut labels (uint8 H x W) from colour and/or depth votes (0 = no vote).

    Both cues: sure plant when both say plant and one is sure; probable plant
    when both say plant, when depth says probably far but colour says plant,
    or when depth says surely near and colour only probably not plant;
    sure background when depth is surely far; probable background otherwise.
    Where a cue has no vote the other decides, downgraded to probable.
    """
    if colour is None and depth is None:
        raise ImageError("no cue to segment with: give a colour index or a disparity/depth map")
    shape = (colour if colour is not None else depth).shape
    if colour is None or depth is None:
        v = colour if colour is not None else depth
        out = np.full(shape, GC_PR_BGD, np.uint8)
        out[v == SURE_FG] = GC_FGD
        out[v == PROB_FG] = GC_PR_FGD
        out[v == SURE_BG] = GC_BGD
        return out
    out = np.full(shape, GC_PR_BGD, np.uint8)
    c, d = colour, depth
    both_fg = (c > 0) & (d > 0)
    out[both_fg] = GC_PR_FGD
    out[both_fg & ((c == SURE_FG) | (d == SURE_FG))] = GC_FGD
    out[(d == PROB_BG) & (c > 0)] = GC_PR_FGD
    out[(d == SURE_FG) & (c == PROB_BG)] = GC_PR_FGD
    out[d == SURE_BG] = GC_BGD
    only_c = (d == 0) & (c != 0)
    out[only_c & (c > 0)] = GC_PR_FGD
    only_d = (c == 0) & (d != 0)
    out[only_d & (d > 0)] = GC_PR_FGD
    return out


def soften_edges(votes: np.ndarray, edge_px: int) -> np.ndarray:
    """Downgrade "sure" votes within ``edge_px`` pixels of the other class to "probable".

    Block matchers fatten near objects by about half their window, so the
    depth cue is unsure along depth edges; GrabCut decides there by colour.
    """
    if edge_px <= 0:
        return votes
    import cv2

    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * edge_px + 1, 2 * edge_px + 1))
    out = votes.copy()
    fg = (votes > 0).astype(np.uint8)
    bg = (votes < 0).astype(np.uint8)
    near_bg = cv2.dilate(bg, k).astype(bool)
    near_fg = cv2.dilate(fg, k).astype(bool)
    out[(votes == SURE_FG) & near_bg] = PROB_FG
    out[(votes == SURE_BG) & near_fg] = PROB_BG
    return out


def _depth_and_colour_votes(img, disparity, depth, index, disparity_range, depth_range, edge_px):
    h, w = img.shape[:2]
    if disparity is not None and depth is not None:
        raise ImageError("give either a disparity or a depth map, not both")
    depth_votes = None
    if disparity is not None or depth is not None:
        arr = np.asarray(disparity if disparity is not None else depth, np.float64)
        if arr.ndim == 3:
            arr = arr[..., 0]
        if arr.shape != (h, w):
            raise ImageError(f"{'disparity' if disparity is not None else 'depth'} map is "
                             f"{arr.shape[1] if arr.ndim > 1 else '?'}x{arr.shape[0]} but the image "
                             f"is {w}x{h}; it must be registered to the image")
        arr = arr.copy()
        if disparity is not None:
            arr[~(arr >= 0)] = np.nan
            near = arr
            rng = disparity_range
        else:
            near = -arr
            rng = None if depth_range is None else (-float(depth_range[1]), -float(depth_range[0]))
        if not np.isfinite(near).any():
            raise ImageError("the disparity/depth map has no valid value")
        depth_votes = range_votes(near, *rng) if rng is not None else otsu_votes(near)[0]
        depth_votes = soften_edges(depth_votes, edge_px)
    colour_votes = None
    if index != "none":
        if index not in INDICES:
            raise ImageError(f"unknown index {index!r}; choose one of {', '.join(INDICES)} or 'none'")
        vi = vegetation_index(img, index)
        if index == "exr":
            vi = -vi  # high = plant
        within = None if depth_votes is None else (depth_votes > 0)
        if within is not None and within.sum() < 2:
            within = None
        colour_votes = otsu_votes(vi, within=within)[0]
    return colour_votes, depth_votes


def _use_colour_model(colour_model, index: str, has_depth: bool) -> bool:
    if colour_model is None:
        return index == "none" and has_depth
    if colour_model:
        if not has_depth:
            raise ImageError("colour_model learns from the depth cue: give a disparity or depth map")
        if index != "none":
            raise ImageError(f"colour_model replaces the vegetation index: use index='none', "
                             f"not {index!r}")
        return True
    return False


def _seed(image_bgr, disparity, depth, index, disparity_range, depth_range, edge_px, colour_model):
    """Seed labels and, when a colour model was learned, ``(plant_gmm, background_gmm)``."""
    img = to_bgr(np.asarray(image_bgr), "image")
    has_depth = disparity is not None or depth is not None
    learn = _use_colour_model(colour_model, index, has_depth)
    colour_votes, depth_votes = _depth_and_colour_votes(img, disparity, depth, index, disparity_range,
                                                        depth_range, edge_px)
    labels = combine_votes(colour_votes, depth_votes)
    if not learn:
        return labels, None
    import cv2

    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * TRAIN_MARGIN_PX + 1,) * 2)
    plant = cv2.erode((labels == GC_FGD).astype(np.uint8), k).astype(bool)
    background = labels == GC_BGD
    if plant.sum() < MIN_SAMPLES or background.sum() < MIN_SAMPLES:
        if colour_model:
            raise ImageError(f"too few sure pixels to learn colour models from the depth cue "
                             f"({int(plant.sum())} plant, {int(background.sum())} background; "
                             f"need {MIN_SAMPLES} each)")
        return labels, None
    llr, plant_gmm, background_gmm = colour_log_ratio(img, plant, background)
    return relabel_by_colour(labels, llr, SURE_LOG_RATIO), (plant_gmm, background_gmm)


def plant_seed(image_bgr, disparity=None, depth=None, index: str = "exg", disparity_range=None,
               depth_range=None, edge_px: int = 4, colour_model: bool | None = None) -> np.ndarray:
    """GrabCut seed labels (H, W) uint8 from the colour and depth cues (see module doc).

    Args:
        image_bgr: uint8 BGR image.
        disparity: optional (H, W) disparity on the image's grid (pixels; high =
            near; negative or non-finite = unknown).
        depth: optional (H, W) depth or distance (low = near; non-finite = unknown).
        index: ``"exg"``, ``"exgr"`` (ExG - ExR) or ``"none"`` (no colour cue).
        disparity_range, depth_range: optional ``(lo, hi)`` plant range instead
            of an automatic threshold.
        edge_px: width (pixels) of the unsure band of the depth cue along depth edges.
        colour_model: learn plant and background colour models from the depth
            cue's sure pixels and relabel the seed with them
            (:func:`~canopy_stereo.segmentation.colour_model.relabel_by_colour`).
            ``None`` (default): exactly when ``index="none"`` and a depth cue is
            given (skipped if the depth cue is sure of fewer than 50 pixels of
            either class); ``True`` requires both (else :class:`ImageError`);
            ``False``: the depth votes alone.
    """
    return _seed(image_bgr, disparity, depth, index, disparity_range, depth_range, edge_px,
                 colour_model)[0]


def auto_plant_mask(image_bgr, disparity=None, depth=None, index: str = "exg", disparity_range=None,
                    depth_range=None, iterations: int = 5, refine: bool = True,
                    min_region: int | None = None, edge_px: int = 4,
                    colour_model: bool | None = None) -> np.ndarray:
    """Plant mask without interaction (uint8 (H, W), 255 = plant).

    Depth input: the disparity of the image on its own grid (e.g. the rectified
    left image and ``canopy-stereo disparity``'s D.pfm) or the distance of the
    points of ``reconstruct_pair(...).organized`` from the left camera centre on
    the original image; the default matcher output (ELAS, or SGBM) is right:
    the holes its left-right check leaves are decided by colour.

    Args:
        image_bgr: uint8 BGR image.
        disparity, depth: optional depth cue registered to the image (see :func:`plant_seed`).
        index: colour cue ``"exg"``, ``"exgr"`` or ``"none"``.
        disparity_range, depth_range: optional plant range for the depth cue.
        iterations: GrabCut iterations (with a learned colour model GrabCut cuts
            once with the models fixed, and this is not used).
        refine: run GrabCut on the seed (else the seed's plant labels are the mask).
        min_region: drop plant regions smaller than this many pixels
            (default: 0.05 % of the image).
        edge_px: unsure band of the depth cue along depth edges (pixels).
        colour_model: learn the colour cue from the depth cue (see
            :func:`plant_seed`); default: with ``index="none"`` and a depth cue.
    """
    if refine and int(iterations) < 1:
        raise ImageError(f"GrabCut needs at least 1 iteration, got {iterations}")
    seed, models = _seed(image_bgr, disparity, depth, index, disparity_range, depth_range, edge_px,
                         colour_model)
    fg = (seed == GC_FGD) | (seed == GC_PR_FGD)
    if not fg.any():
        raise ImageError("no pixel looks like plant: try another index, a depth cue or a rectangle")
    if not refine:
        labels = seed
    elif models is not None:
        labels = grabcut_with_models(image_bgr, seed, *models)
    else:
        labels = grabcut_labels(image_bgr, seed, iterations)
    mask = (labels == GC_FGD) | (labels == GC_PR_FGD)
    if min_region is None:
        min_region = max(1, int(0.0005 * mask.size))
    mask = clean_mask_regions(mask, min_pixels=min_region)
    return np.where(mask, 255, 0).astype(np.uint8)
