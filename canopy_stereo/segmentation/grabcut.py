"""GrabCut (Rother, Kolmogorov & Blake 2004) from a rectangle or from a mask.

The paper's interaction: the user draws a rough rectangle around the plant
and GrabCut separates it from the background (colour models of both, refined
by iterated graph cuts). A mask can seed it instead: either OpenCV GrabCut
labels or a rough binary plant mask.
"""
from __future__ import annotations

import cv2
import numpy as np

from canopy_stereo.errors import ImageError
from canopy_stereo.io.images import to_bgr
from canopy_stereo.segmentation.frozen_cut import GRABCUT_MAX_SHARE, frozen_model_cut, learn_models

#: OpenCV GrabCut labels.
GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD = cv2.GC_BGD, cv2.GC_FGD, cv2.GC_PR_BGD, cv2.GC_PR_FGD

#: State of OpenCV's generator before each GrabCut start: its colour models begin with a k-means
#: whose centres are drawn from the calling thread's generator (``cv::theRNG``), so without it
#: the same image cut the same way gives a different mask after whatever ran before in the
#: thread (IoU down to 0.76 seen). Seed 0 gives a fresh thread's state (OpenCV's default,
#: 0xFFFFFFFF): every cut is the one a fresh process makes.
GRABCUT_RNG_SEED = 0


def _opencv_grabcut(*args) -> None:
    """``cv2.grabCut(*args)`` from :data:`GRABCUT_RNG_SEED` (the calling thread's OpenCV
    generator is reset: the cut depends only on its inputs)."""
    cv2.setRNGSeed(GRABCUT_RNG_SEED)
    cv2.grabCut(*args)


def _check_image(image_bgr) -> np.ndarray:
    img = to_bgr(np.asarray(image_bgr), "image")
    if img.shape[0] < 2 or img.shape[1] < 2:
        raise ImageError(f"image is too small for GrabCut: {img.shape[1]}x{img.shape[0]}")
    return np.ascontiguousarray(img)


def _check_iterations(iterations) -> int:
    it = int(iterations)
    if it < 1:
        raise ImageError(f"GrabCut needs at least 1 iteration, got {iterations}")
    return it


def labels_to_mask(labels: np.ndarray) -> np.ndarray:
    """uint8 mask, 255 where GrabCut labels say (probably) plant, else 0."""
    return np.where((labels == GC_FGD) | (labels == GC_PR_FGD), 255, 0).astype(np.uint8)


def grabcut_labels(image_bgr, labels: np.ndarray, *, iterations: int = 5) -> np.ndarray:
    """Run GrabCut from initial labels; returns the final (H, W) uint8 labels.

    Args:
        image_bgr: uint8 colour (or grey) image.
        labels: (H, W) uint8 with values in ``{GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD}``.
        iterations: GrabCut iterations.

    Raises:
        ImageError: size mismatch, or labels without any (probable) plant or
            without any (probable) background pixel.
    """
    img = _check_image(image_bgr)
    it = _check_iterations(iterations)
    lab = np.asarray(labels)
    if lab.shape != img.shape[:2]:
        raise ImageError(f"mask is {lab.shape[1] if lab.ndim > 1 else '?'}x{lab.shape[0]} "
                         f"but the image is {img.shape[1]}x{img.shape[0]}")
    lab = lab.astype(np.uint8).copy()
    if lab.max() > 3:
        raise ImageError("GrabCut labels must be 0 (background), 1 (plant), 2 (probable background) "
                         "or 3 (probable plant)")
    fg = (lab == GC_FGD) | (lab == GC_PR_FGD)
    bg = (lab == GC_BGD) | (lab == GC_PR_BGD)
    if not fg.any():
        raise ImageError("the GrabCut seed has no plant pixel (the mask is empty)")
    if not bg.any():
        raise ImageError("the GrabCut seed has no background pixel (the mask covers the whole image)")
    if not ((lab == GC_PR_FGD) | (lab == GC_PR_BGD)).any():
        return lab  # nothing left to decide
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    # OpenCV's start (both colour models from k-means of their side's pixels), then its iterations
    # with the cut on the undecided pixels only; many undecided pixels: OpenCV's own (the same)
    whole = np.count_nonzero(lab >= 2) > GRABCUT_MAX_SHARE * lab.size
    try:
        _opencv_grabcut(img, lab, None, bgd, fgd, it if whole else 0, cv2.GC_INIT_WITH_MASK)
    except cv2.error as exc:
        raise ImageError(f"GrabCut failed on this seed: {str(exc).strip().splitlines()[-1]}") from None
    if whole:
        return lab
    for _ in range(it):  # OpenCV's iterations, the graph cut on the undecided pixels only
        bgd, fgd = learn_models(img, lab, bgd, fgd)
        lab = frozen_model_cut(img, lab, bgd, fgd)
    return lab


def clip_rect(rect, size) -> tuple[int, int, int, int]:
    """``rect`` ``(x, y, w, h)`` (pixels) clipped to an image of ``size`` ``(width, height)``,
    as ``(x, y, w, h)``; raises :class:`ImageError` when it is not 4 numbers, has no area,
    lies (almost) outside the image or covers all of it (GrabCut needs background outside)."""
    try:
        x, y, w, h = (int(round(float(v))) for v in rect)
    except (TypeError, ValueError):
        raise ImageError(f"rectangle must be 4 numbers x, y, w, h; got {rect!r}") from None
    W, H = (int(v) for v in size)
    if w <= 0 or h <= 0:
        raise ImageError(f"rectangle must have positive width and height, got {w}x{h}")
    x0, y0 = max(x, 0), max(y, 0)
    x1, y1 = min(x + w, W), min(y + h, H)
    if x1 - x0 < 2 or y1 - y0 < 2:
        raise ImageError(f"rectangle {x},{y},{w},{h} lies (almost) outside the {W}x{H} image")
    if x0 == 0 and y0 == 0 and x1 == W and y1 == H:
        raise ImageError("the rectangle covers the whole image; GrabCut needs background outside it")
    return x0, y0, x1 - x0, y1 - y0


def grabcut_rect(image_bgr, rect, *, iterations: int = 5) -> np.ndarray:
    """Plant mask from a rectangle around the plant (the paper's interaction).

    Args:
        image_bgr: uint8 BGR (or grey) image.
        rect: ``(x, y, w, h)`` in pixels; everything outside is background.
            Clipped to the image; some image must remain outside it.
        iterations: GrabCut iterations.

    Returns:
        (H, W) uint8 mask, 255 = plant.
    """
    img = _check_image(image_bgr)
    it = _check_iterations(iterations)
    H, W = img.shape[:2]
    x0, y0, cw, ch = clip_rect(rect, (W, H))
    x1, y1 = x0 + cw, y0 + ch
    labels = np.full((H, W), GC_BGD, np.uint8)
    labels[y0:y1, x0:x1] = GC_PR_FGD
    bgd = np.zeros((1, 65), np.float64)
    fgd = np.zeros((1, 65), np.float64)
    try:
        _opencv_grabcut(img, labels, (x0, y0, x1 - x0, y1 - y0), bgd, fgd, it, cv2.GC_INIT_WITH_RECT)
    except cv2.error as exc:
        raise ImageError(f"GrabCut failed on this rectangle: {str(exc).strip().splitlines()[-1]}") from None
    return labels_to_mask(labels)


def grabcut_mask(image_bgr, mask, *, iterations: int = 5, margin_px: int = 0) -> np.ndarray:
    """Plant mask refined by GrabCut from an initial mask.

    Args:
        image_bgr: uint8 BGR (or grey) image.
        mask: (H, W) initial mask, one of
            * GrabCut labels (uint8 with values 0..3: background, plant,
              probable background, probable plant);
            * a rough binary plant mask (bool, or uint8 0/255): plant pixels
              are probable plant, the others probable background; with
              ``margin_px > 0`` pixels deeper than ``margin_px`` inside the
              plant become sure plant and those farther than ``margin_px``
              outside it sure background.
        iterations: GrabCut iterations.
        margin_px: see above.

    Returns:
        (H, W) uint8 mask, 255 = plant.
    """
    m = np.asarray(mask)
    if m.ndim == 3:
        m = m.max(axis=2)
    if m.ndim != 2:
        raise ImageError(f"mask must be (H, W), got shape {m.shape}")
    if m.dtype != np.bool_ and m.size and m.max() <= 3 and np.issubdtype(m.dtype, np.integer):
        labels = m.astype(np.uint8)
    else:
        plant = m.astype(bool)
        labels = np.where(plant, GC_PR_FGD, GC_PR_BGD).astype(np.uint8)
        if margin_px > 0:
            k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1, 2 * margin_px + 1))
            inner = cv2.erode(plant.astype(np.uint8), k).astype(bool)
            outer = cv2.dilate(plant.astype(np.uint8), k).astype(bool)
            labels[inner] = GC_FGD
            labels[~outer] = GC_BGD
    return labels_to_mask(grabcut_labels(image_bgr, labels, iterations=iterations))


def compile_cut_kernels() -> None:
    """Load (or, from an empty numba cache, compile) the compiled cut's kernels: a GrabCut on
    a small synthetic image whose seed leaves few pixels undecided, the path real frames take
    (a seed with many undecided pixels goes to OpenCV's own GrabCut and compiles nothing).
    Nodes call it before they subscribe, so that no frame waits for a compilation."""
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    img[8:24, 8:24] = (40, 160, 60) + rng.integers(0, 20, (16, 16, 3), dtype=np.uint8)
    lab = np.full((32, 32), cv2.GC_BGD, np.uint8)
    lab[10:22, 10:22] = cv2.GC_FGD
    lab[7:10, 7:25] = lab[22:25, 7:25] = cv2.GC_PR_FGD  # a thin undecided band: the compiled cut
    lab[10:22, 7:10] = lab[10:22, 22:25] = cv2.GC_PR_BGD
    grabcut_labels(img, lab, iterations=2)
