"""The package's one plant seeder: colour and depth cues seed GrabCut, no interaction.

One seeder, one settings object (:class:`SeederSettings`), two presets:
:data:`IMAGE_SEEDER` (``canopy-stereo segment``, the batch and paper pipelines:
ExG + depth at full resolution) and :data:`VIDEO_SEEDER` (``segment_node``:
saturation at a quarter of the resolution, fast enough for video; with its
``depth_cue`` parameter the node adds the disparity as the CLI does).

Each cue votes per pixel on a four-level scale, the GrabCut labels: sure
background, probable background, probable plant, sure plant. A cue is split
in two classes by Otsu's threshold; values beyond the midpoint between the
threshold and a class mean are "sure", the others "probable" (or, with
``sure_margin``, values more than that many 8-bit index units from the
threshold, as the video preset does).

* Colour: a vegetation index on normalised chromaticity (ExG, or ExG - ExR),
  or the HSV saturation (a colourful plant before a neutral backdrop), high =
  plant. Good for green plants on soil, a bench or a grey backdrop. Instead of
  an index: ``border`` (everything but a 5 % frame is probably plant) or a
  rectangle around the plant (the paper's interaction; outside = sure background).
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
(``colour_cue="none"``) or a rectangle (:func:`grabcut_rect`). With
``"none"`` a pot at the plant's distance stays in the mask, so draw a
rectangle that leaves it out, or cut it with a depth range.

Without an index the colour cue is learned instead (``colour_model``, on by
default there; :mod:`canopy_stereo.segmentation.colour_model`): colour models
of plant and background are fitted to the pixels the depth cue is sure of
(near and away from depth edges; far), and their log likelihood ratio
relabels the seed: it removes the background gaps between leaves that a
window matcher fills with the leaves' disparity, and decides the pixels
without depth (occlusions, the image border the other camera does not see).
GrabCut then cuts once with those models kept fixed.

GrabCut is costly, so with ``scale < 1`` the image (and the depth map) is
seeded and cut at that fraction of its size and the mask resized back.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import cv2
import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.images import to_bgr
from canopy_stereo.segmentation.cleaning import clean_mask_regions
from canopy_stereo.segmentation.colour_model import (
    MIN_SAMPLES,
    SURE_LOG_RATIO,
    colour_log_ratio,
    grabcut_with_models,
    relabel_by_colour,
)
from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD, grabcut_labels, labels_to_mask
from canopy_stereo.segmentation.indices import class_means, otsu_threshold, vegetation_index

#: Vote values of a cue.
SURE_BG, PROB_BG, PROB_FG, SURE_FG = -2, -1, 1, 2
#: Margin (pixels) by which the sure-plant pixels of the depth seed are eroded
#: before a colour model is learned from them.
TRAIN_MARGIN_PX = 2


def otsu_votes(values: np.ndarray, valid: np.ndarray | None = None, *, within: np.ndarray | None = None):
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
    ref = colour if colour is not None else depth
    assert ref is not None  # (one of the two, checked above)
    shape = ref.shape
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
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * edge_px + 1, 2 * edge_px + 1))
    out = votes.copy()
    fg = (votes > 0).astype(np.uint8)
    bg = (votes < 0).astype(np.uint8)
    near_bg = cv2.dilate(bg, k).astype(bool)
    near_fg = cv2.dilate(fg, k).astype(bool)
    out[(votes == SURE_FG) & near_bg] = PROB_FG
    out[(votes == SURE_BG) & near_fg] = PROB_BG
    return out




#: Colour cues of the seeder: vegetation indices (ExG, ExG - ExR, ExR with low = plant), the HSV
#: saturation, ``border`` (a 5 % frame is sure background, the rest probable plant) and
#: ``none`` (no colour cue: the depth cue alone, or with a learned colour model).
COLOUR_CUES = ("exg", "exgr", "exr", "saturation", "border", "none")
#: Automatic initialisations of ``segment_node`` and :func:`segment_plant` (without a depth cue).
AUTO_INITS = ("saturation", "exg", "border")
#: Value range of each index, mapped to 0..255 when ``sure_margin`` is set.
_INDEX_RANGE = {"exg": (-1.0, 2.0), "exgr": (-2.4, 3.0), "exr": (-1.4, 1.0), "saturation": (0.0, 255.0)}


def _setting(default, description: str, *, unit: str = "", minimum=None, maximum=None, choices=None,
             node: bool = True, parameter: str | None = None):
    """A :class:`SeederSettings` field with its documentation: what ``segment_node`` declares
    (as ``parameter``, default the field's name; ``node=False``: not a node parameter)."""
    return field(default=default, metadata={"description": description, "unit": unit, "minimum": minimum,
                                            "maximum": maximum, "choices": choices, "node": node,
                                            "parameter": parameter})


@dataclass(frozen=True)
class SeederSettings:
    """How the plant seeder seeds and cuts (one object for the CLI, the pipelines and
    ``segment_node``, whose parameters are derived from these fields: :func:`seeder_fields`).

    Attributes:
        colour_cue: ``"exg"`` (excess green), ``"exgr"`` (ExG - ExR), ``"exr"`` (excess
            red, low = plant), ``"saturation"``
            (HSV saturation), ``"border"`` (all but a 5 % frame is probably plant) or
            ``"none"`` (no colour cue; needs a depth cue).
        depth_cue: use a disparity or depth map registered to the image (near = plant).
            Off: passing a map is an error.
        sure_margin: probable band on each side of the colour cue's Otsu threshold, in
            8-bit index units (0..255, the index mapped linearly to 0..255); None: up to
            half-way to each class mean.
        disparity_range: ``(lo, hi)`` plant disparity in pixels instead of Otsu's threshold.
        depth_range: ``(lo, hi)`` plant depth (the map's units) instead of Otsu's threshold.
        edge_px: width in pixels (of the processed image) of the unsure band of the depth
            cue along depth edges, 0..50.
        colour_model: learn plant and background colour models from the depth cue's sure
            pixels and relabel the seed with them
            (:func:`~canopy_stereo.segmentation.colour_model.relabel_by_colour`).
            None: exactly when ``colour_cue="none"`` and a depth cue is given (skipped
            if the depth cue is sure of fewer than 50 pixels of either class); True
            requires both (else :class:`ImageError`); False: the depth votes alone.
        scale: processing scale in (0, 1]: the image (and depth map) is seeded and cut at
            this fraction of its size and the mask resized back.
        iterations: GrabCut iterations, 1..100 (with a learned colour model GrabCut cuts
            once with the models fixed, and this is not used).
        refine: run GrabCut on the seed (else the seed's plant labels are the mask).
        min_region: drop plant regions smaller than this many pixels of the full image
            (None: 0.05 % of the image; 0: keep all).
        strict: raise :class:`ImageError` when no pixel looks like plant; False: return an
            empty mask (and a full one when no pixel looks like background), as a video
            node needs.
    """

    colour_cue: str = _setting("exg", "automatic initialisation (colour cue of the seed) when rect is empty",
                               choices=COLOUR_CUES, parameter="auto_init")
    depth_cue: bool = _setting(True, "use the disparity (near = plant) as a cue")
    sure_margin: float | None = _setting(None, "probable band on each side of the colour cue's Otsu "
                                         "threshold; -1 = half-way to the class means",
                                         unit="8-bit index units", minimum=-1.0, maximum=127.0)
    disparity_range: tuple | None = _setting(None, "plant disparity range [lo, hi]", unit="px", node=False)
    depth_range: tuple | None = _setting(None, "plant depth range [lo, hi]", unit="depth map units", node=False)
    edge_px: int = _setting(4, "unsure band of the depth cue along depth edges", unit="px",
                            minimum=0, maximum=50)
    colour_model: bool | None = _setting(None, "learn colour models from the depth cue (auto: with colour_cue "
                                         "none and a depth cue)",
                                         choices=("auto", "on", "off"))
    scale: float = _setting(1.0, "processing scale: images are segmented at this fraction of their size "
                            "and the mask resized back", minimum=0.01, maximum=1.0)
    iterations: int = _setting(5, "GrabCut iterations", minimum=1, maximum=100)
    refine: bool = _setting(True, "run GrabCut on the seed (false: the seed is the mask)")
    min_region: int | None = _setting(None, "drop plant regions smaller than this; -1 = 0.05 % of the image",
                                      unit="px", minimum=-1, maximum=10**8)
    strict: bool = _setting(True, "error when no pixel looks like plant", node=False)

    def __post_init__(self):
        if self.colour_cue not in COLOUR_CUES:
            raise ImageError(f"unknown index {self.colour_cue!r}; choose one of {', '.join(COLOUR_CUES)}")
        if self.sure_margin is not None and not 0 <= float(self.sure_margin) <= 127:
            raise CanopyStereoError(f"sure_margin must be in [0, 127] index units, got {self.sure_margin}")
        for name in ("disparity_range", "depth_range"):
            rng = getattr(self, name)
            if rng is not None and (len(rng) != 2 or not float(rng[1]) > float(rng[0])):
                raise ImageError(f"range must have hi > lo, got {list(rng)}")
        if not 0 <= int(self.edge_px) <= 50:
            raise CanopyStereoError(f"edge_px must be in [0, 50] pixels, got {self.edge_px}")
        if not 0 < float(self.scale) <= 1:
            raise CanopyStereoError(f"scale must be in (0, 1], got {self.scale}")
        if self.refine and int(self.iterations) < 1:
            raise ImageError(f"GrabCut needs at least 1 iteration, got {self.iterations}")
        if self.min_region is not None and int(self.min_region) < 0:
            raise CanopyStereoError(f"min_region must be >= 0 pixels (or None), got {self.min_region}")

    def replace(self, **changes) -> SeederSettings:
        """A copy with ``changes`` (validated)."""
        return replace(self, **changes)


#: The CLI's, batch's and paper pipeline's seeder: ExG + depth at full resolution, the
#: sure band half-way to the class means, small regions dropped, an error when nothing is plant.
IMAGE_SEEDER = SeederSettings()
#: ``segment_node``'s seeder: HSV saturation (a colourful plant before a neutral backdrop)
#: with a 12-unit probable band, a quarter of the resolution, 3 GrabCut iterations, no
#: region cleaning, an empty mask when nothing is plant; the depth cue when the node has one.
VIDEO_SEEDER = SeederSettings(colour_cue="saturation", depth_cue=False, sure_margin=12.0, scale=0.25,
                              iterations=3, min_region=0, strict=False)


def seeder_fields(preset: SeederSettings = IMAGE_SEEDER) -> list[dict]:
    """The settings a node declares as parameters, derived from :class:`SeederSettings`.

    Each entry: ``name`` (the parameter's), ``field`` (the settings field's), ``kind``
    (``"number"``, ``"text"`` or ``"flag"``), ``default``
    (``preset``'s value encoded with :func:`encode_setting`), ``description`` (with the
    unit), and ``minimum``/``maximum`` (numbers) or ``choices`` (text). The range fields
    (per image, not per node) are left out.
    """
    out = []
    for f in fields(SeederSettings):
        meta = f.metadata
        if not meta["node"]:
            continue
        default = encode_setting(f.name, getattr(preset, f.name))
        kind = "flag" if isinstance(default, bool) else "text" if isinstance(default, str) else "number"
        desc = meta["description"] + (f" ({meta['unit']})" if meta["unit"] else "")
        out.append({"name": meta["parameter"] or f.name, "field": f.name, "kind": kind, "default": default,
                    "description": desc,
                    "minimum": meta["minimum"], "maximum": meta["maximum"], "choices": meta["choices"]})
    return out


def encode_setting(name: str, value):
    """A :class:`SeederSettings` value as a ROS parameter value: ``colour_model`` None/True/False
    -> ``"auto"``/``"on"``/``"off"``; ``sure_margin`` and ``min_region`` None -> -1."""
    if name == "colour_model":
        return {None: "auto", True: "on", False: "off"}[value]
    if name == "sure_margin":
        return -1.0 if value is None else float(value)
    if name == "min_region":
        return -1 if value is None else int(value)
    return value


def decode_setting(name: str, value):
    """Inverse of :func:`encode_setting` (raises :class:`CanopyStereoError` on a bad value)."""
    if name == "colour_model":
        table = {"auto": None, "on": True, "off": False}
        if value not in table:
            raise CanopyStereoError(f"colour_model must be auto, on or off, got {value!r}")
        return table[value]
    if name == "sure_margin":
        return None if float(value) < 0 else float(value)
    if name == "min_region":
        return None if int(value) < 0 else int(value)
    if name in ("edge_px", "iterations"):
        return int(value)
    if name == "scale":
        return float(value)
    if name in ("depth_cue", "refine", "strict"):
        return bool(value)
    return str(value) if name == "colour_cue" else value


def _scaled_map(arr, size):
    """A (H, W) map resized to ``size`` = (w, h) by nearest neighbour (no mixing of depths)."""
    if (arr.shape[1], arr.shape[0]) == size:
        return arr
    return cv2.resize(arr, size, interpolation=cv2.INTER_NEAREST)


def _depth_votes(disparity, depth, settings: SeederSettings):
    """Votes of the depth cue (maps already checked and scaled to the processed image)."""
    arr = np.asarray(disparity if disparity is not None else depth, np.float64).copy()
    if disparity is not None:
        arr[~(arr >= 0)] = np.nan
        near = arr
        rng = settings.disparity_range
    else:
        near = -arr
        rng = (None if settings.depth_range is None else
               (-float(settings.depth_range[1]), -float(settings.depth_range[0])))
    if not np.isfinite(near).any():
        raise ImageError("the disparity/depth map has no valid value")
    votes = range_votes(near, *rng) if rng is not None else otsu_votes(near)[0]
    return soften_edges(votes, int(settings.edge_px))


def _index_votes(img, colour_cue: str, sure_margin, within):
    """Votes of a colour index (high = plant), thresholded by Otsu among ``within`` (or all)."""
    if colour_cue == "saturation":
        vi = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)[..., 1].astype(np.float64)
    else:
        vi = vegetation_index(img, colour_cue)
        if colour_cue == "exr":
            vi = -vi  # high = plant
    if sure_margin is None:
        return otsu_votes(vi, within=within)[0]
    lo, hi = _INDEX_RANGE[colour_cue]
    index8 = (vi.astype(np.uint8) if colour_cue == "saturation" else
              np.clip((vi - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8))
    sample = index8 if within is None else index8[within].reshape(-1, 1)
    thr, _ = cv2.threshold(sample, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    m = float(sure_margin)
    votes = np.full(index8.shape, SURE_BG, np.int8)
    votes[index8 >= thr - m] = PROB_BG
    votes[index8 >= thr] = PROB_FG
    votes[index8 >= thr + m] = SURE_FG
    return votes


def _frame_votes(shape, rect):
    """Votes of a rectangle (inside probable plant, outside sure background), or of the
    ``border`` cue when ``rect`` is None (a 5 % frame is sure background)."""
    h, w = shape
    votes = np.full((h, w), SURE_BG, np.int8)
    if rect is None:
        mx, my = max(1, w // 20), max(1, h // 20)
        votes[my:h - my, mx:w - mx] = PROB_FG
    else:
        x, y, rw, rh = rect
        votes[y:y + rh, x:x + rw] = PROB_FG
    return votes


def _use_colour_model(colour_model, colour_cue: str, has_depth: bool) -> bool:
    if colour_model is None:
        return colour_cue == "none" and has_depth
    if colour_model:
        if not has_depth:
            raise ImageError("colour_model learns from the depth cue: give a disparity or depth map")
        if colour_cue != "none":
            raise ImageError(f"colour_model replaces the vegetation index: use index='none', "
                             f"not {colour_cue!r}")
        return True
    return False


def _prepare(image_bgr, disparity, depth, settings: SeederSettings, rect):
    """``(image at the processing scale, its disparity, its depth, its rectangle)`` after checks."""
    img = to_bgr(np.asarray(image_bgr), "image")
    h, w = img.shape[:2]
    if disparity is not None and depth is not None:
        raise ImageError("give either a disparity or a depth map, not both")
    maps: list[np.ndarray | None] = []
    for name, arr in (("disparity", disparity), ("depth", depth)):
        if arr is None:
            maps.append(None)
            continue
        if not settings.depth_cue:
            raise CanopyStereoError(f"a {name} map was given but the seeder's depth_cue is off")
        arr = np.asarray(arr, np.float64)
        if arr.ndim == 3:
            arr = arr[..., 0]
        if arr.shape != (h, w):
            raise ImageError(f"{name} map is {arr.shape[1] if arr.ndim > 1 else '?'}x{arr.shape[0]} "
                             f"but the image is {w}x{h}; it must be registered to the image")
        maps.append(arr)
    srect = None
    if rect is not None:
        x, y, rw, rh = (int(v) for v in rect)
        x0, y0 = max(0, x), max(0, y)
        x1, y1 = min(w, x + rw), min(h, y + rh)
        if x1 - x0 < 2 or y1 - y0 < 2:
            raise CanopyStereoError(f"rectangle {list(rect)} does not overlap the {w}x{h} image")
        srect = (x0, y0, x1 - x0, y1 - y0)
    if settings.scale == 1:
        return img, maps[0], maps[1], srect
    size = (max(8, round(w * settings.scale)), max(8, round(h * settings.scale)))
    small = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    if srect is not None:
        fx, fy = size[0] / w, size[1] / h
        x0, y0, rw, rh = srect
        srect = (int(x0 * fx), int(y0 * fy), max(2, int(rw * fx)), max(2, int(rh * fy)))
    maps = [None if m is None else _scaled_map(m, size) for m in maps]
    return small, maps[0], maps[1], srect


def _seed(img, disparity, depth, settings: SeederSettings, rect):
    """Seed labels of a prepared image and, when a colour model was learned,
    ``(plant_gmm, background_gmm)``."""
    has_depth = disparity is not None or depth is not None
    cue = settings.colour_cue
    learn = rect is None and _use_colour_model(settings.colour_model, cue, has_depth)
    depth_votes = _depth_votes(disparity, depth, settings) if has_depth else None
    colour_votes = None
    if rect is not None or cue == "border":
        colour_votes = _frame_votes(img.shape[:2], rect)
    elif cue != "none":
        within = None if depth_votes is None else (depth_votes > 0)
        if within is not None and within.sum() < 2:
            within = None
        colour_votes = _index_votes(img, cue, settings.sure_margin, within)
    labels = combine_votes(colour_votes, depth_votes)
    if not learn:
        return labels, None
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * TRAIN_MARGIN_PX + 1,) * 2)
    plant = cv2.erode((labels == GC_FGD).astype(np.uint8), k).astype(bool)
    background = labels == GC_BGD
    if plant.sum() < MIN_SAMPLES or background.sum() < MIN_SAMPLES:
        if settings.colour_model:
            raise ImageError(f"too few sure pixels to learn colour models from the depth cue "
                             f"({int(plant.sum())} plant, {int(background.sum())} background; "
                             f"need {MIN_SAMPLES} each)")
        return labels, None
    llr, plant_gmm, background_gmm = colour_log_ratio(img, plant, background)
    return relabel_by_colour(labels, llr, sure=SURE_LOG_RATIO), (plant_gmm, background_gmm)


def seed_labels(image_bgr, settings: SeederSettings = IMAGE_SEEDER, *, disparity=None, depth=None,
                rect=None) -> np.ndarray:
    """GrabCut seed labels (uint8 (h, w) at the processing scale ``settings.scale``) of
    the seeder (see the module docstring).

    Args:
        image_bgr: uint8 BGR (H, W, 3) image (grey is accepted).
        settings: :class:`SeederSettings` (default :data:`IMAGE_SEEDER`).
        disparity: optional (H, W) disparity on the image's grid (pixels; high = near;
            negative or non-finite = unknown).
        depth: optional (H, W) depth or distance (low = near; non-finite = unknown).
        rect: optional ``(x, y, width, height)`` rectangle (pixels of the image) around
            the plant, instead of the colour cue.
    """
    img, disp, dep, srect = _prepare(image_bgr, disparity, depth, settings, rect)
    return _seed(img, disp, dep, settings, srect)[0]


def plant_mask(image_bgr, settings: SeederSettings = IMAGE_SEEDER, *, disparity=None, depth=None,
               rect=None) -> np.ndarray:
    """Plant mask (uint8 (H, W), 255 = plant) of the one seeder and GrabCut.

    Args: as :func:`seed_labels`. With ``scale < 1`` the image and the map are processed
    at that scale and the mask resized back (nearest 0/255 after linear interpolation).

    Raises :class:`ImageError` on bad input, and with ``settings.strict`` when no pixel
    looks like plant (else an empty mask is returned).
    """
    h, w = np.asarray(image_bgr).shape[:2]
    img, disp, dep, srect = _prepare(image_bgr, disparity, depth, settings, rect)
    seed, models = _seed(img, disp, dep, settings, srect)
    fg = (seed == GC_FGD) | (seed == GC_PR_FGD)
    if not fg.any():
        if settings.strict:
            raise ImageError("no pixel looks like plant: try another index, a depth cue or a rectangle")
        return np.zeros((h, w), np.uint8)
    if not settings.strict and fg.all():
        return np.full((h, w), 255, np.uint8)
    if not settings.refine:
        labels = seed
    elif models is not None:
        labels = grabcut_with_models(img, seed, *models)
    else:
        labels = grabcut_labels(img, seed, iterations=int(settings.iterations))
    mask = labels_to_mask(labels)
    if mask.shape != (h, w):
        mask = cv2.resize(mask, (w, h), interpolation=cv2.INTER_LINEAR)
        cv2.threshold(mask, 127, 255, cv2.THRESH_BINARY, dst=mask)  # in place: >= 128: 255, else 0
    min_region = settings.min_region
    if min_region is None:
        min_region = max(1, int(0.0005 * mask.size))
    if min_region > 0:
        mask = np.where(clean_mask_regions(mask > 0, min_pixels=min_region), 255, 0).astype(np.uint8)
    return mask


def plant_seed(image_bgr, disparity=None, *, depth=None, index: str = "exg", disparity_range=None,
               depth_range=None, edge_px: int = 4, colour_model: bool | None = None) -> np.ndarray:
    """GrabCut seed labels (H, W) uint8 from the colour and depth cues (:data:`IMAGE_SEEDER`
    with these changes; see :class:`SeederSettings` for the options).

    Args:
        image_bgr: uint8 BGR image.
        disparity: optional (H, W) disparity on the image's grid (pixels; high =
            near; negative or non-finite = unknown).
        depth: optional (H, W) depth or distance (low = near; non-finite = unknown).
        index: colour cue (:data:`COLOUR_CUES`: ``"exg"``, ``"exgr"`` (ExG - ExR),
            ``"saturation"``, ``"border"`` or ``"none"``).
        disparity_range, depth_range: optional ``(lo, hi)`` plant range instead
            of an automatic threshold.
        edge_px: width (pixels) of the unsure band of the depth cue along depth edges.
        colour_model: see :attr:`SeederSettings.colour_model`.
    """
    settings = IMAGE_SEEDER.replace(colour_cue=index, disparity_range=disparity_range,
                                    depth_range=depth_range, edge_px=edge_px, colour_model=colour_model)
    return seed_labels(image_bgr, settings, disparity=disparity, depth=depth)


def auto_plant_mask(image_bgr, disparity=None, *, depth=None, index: str = "exg", disparity_range=None,
                    depth_range=None, iterations: int = 5, refine: bool = True,
                    min_region: int | None = None, edge_px: int = 4,
                    colour_model: bool | None = None) -> np.ndarray:
    """Plant mask without interaction (uint8 (H, W), 255 = plant): :func:`plant_mask` with
    :data:`IMAGE_SEEDER` and these changes (see :class:`SeederSettings`).

    Depth input: the disparity of the image on its own grid (e.g. the rectified
    left image and ``canopy-stereo disparity``'s D.pfm) or the distance of the
    points of ``reconstruct_pair(...).organized`` from the left camera centre on
    the original image; the default matcher output (ELAS, or SGBM) is right:
    the holes its left-right check leaves are decided by colour.

    Args:
        image_bgr: uint8 BGR image.
        disparity, depth: optional depth cue registered to the image (see :func:`plant_seed`).
        index: colour cue ``"exg"``, ``"exgr"``, ``"saturation"``, ``"border"`` or ``"none"``.
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
    settings = IMAGE_SEEDER.replace(colour_cue=index, disparity_range=disparity_range,
                                    depth_range=depth_range, iterations=iterations, refine=refine,
                                    min_region=min_region, edge_px=edge_px, colour_model=colour_model)
    return plant_mask(image_bgr, settings, disparity=disparity, depth=depth)


def segment_plant(bgr: np.ndarray, rect=None, *, iterations: int = 3, auto_init: str = "saturation",
                  scale: float = 0.25) -> np.ndarray:
    """Plant mask of a BGR image by GrabCut, fast enough for video (``segment_node``'s
    :data:`VIDEO_SEEDER` with these changes): uint8 (H, W), 255 = plant.

    Args:
        bgr: uint8 (H, W, 3) image.
        rect: ``(x, y, width, height)`` rectangle containing the plant (pixels of
            ``bgr``), or None for the automatic initialisation.
        iterations: GrabCut iterations (>= 1).
        auto_init: ``"saturation"``, ``"exg"`` or ``"border"`` (:data:`AUTO_INITS`).
        scale: processing scale in (0, 1].
    """
    if bgr.ndim != 3 or bgr.shape[2] != 3 or bgr.dtype != np.uint8:
        raise ImageError(f"segmentation needs a uint8 BGR image, got {bgr.dtype} {bgr.shape}")
    if auto_init not in AUTO_INITS:
        raise CanopyStereoError(f"auto_init must be one of {', '.join(AUTO_INITS)}, got {auto_init!r}")
    if iterations < 1:
        raise CanopyStereoError(f"iterations must be >= 1, got {iterations}")
    settings = VIDEO_SEEDER.replace(colour_cue=auto_init, iterations=iterations, scale=scale)
    return plant_mask(bgr, settings, rect=rect)
