"""GrabCut's graph cut with fixed colour models, solved on the undecided pixels only.

OpenCV's ``cv2.grabCut(..., GC_EVAL_FREEZE_MODEL)`` builds a graph over every pixel of
the image and runs max-flow over all of it, although the sure pixels (``GC_BGD``,
``GC_FGD``) cannot change: their terminal link (``lambda = 9 gamma = 450``) outweighs all
their neighbour links together (at most ``4 gamma + 4 gamma / sqrt 2``, about 341). In
a video frame seeded automatically most pixels are sure (on the Plants frames at 160x120
about 9 % are undecided), so :func:`frozen_model_cut` builds the graph of the undecided
(``GC_PR_*``) pixels only: a link to a sure neighbour becomes part of the pixel's
terminal link towards that neighbour's side. The energy is OpenCV's term for term
(``gamma = 50``; ``beta`` from the whole image's 8-neighbour colour differences; data
terms ``-ln`` of the models' densities without the common ``(2 pi)^-3/2``), so the cut
is the same minimum cut; pixels whose side does not change the energy (ties) may differ.
Pixels whose terminal link outweighs all their neighbour links are settled first
(:func:`_fix_decided`), the rest go to a Boykov-Kolmogorov max-flow (numba).

:func:`learn_models` is GrabCut's learning step, so that :func:`~canopy_stereo.segmentation.grabcut.grabcut_labels`
runs OpenCV's iterations (after OpenCV's own k-means start) with this cut.

Colours are BGR (any channel order, the models' own), 0..255. Labels are OpenCV's
GrabCut labels (:data:`~canopy_stereo.segmentation.grabcut.GC_BGD` ...).
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from canopy_stereo.errors import ImageError

#: Share of undecided pixels above which OpenCV's whole-image cut is as fast as this one
#: (large blobs of undecided pixels, e.g. a rectangle seed, grow deep search trees):
#: :func:`frozen_model_cut` then calls ``cv2.grabCut`` (the same cut), and so does
#: :func:`~canopy_stereo.segmentation.grabcut.grabcut_labels` above :data:`GRABCUT_MAX_SHARE`
#: (measured at 160x120 and 640x480 on the Plants and Aloe frames, loaded).
FROZEN_CUT_MAX_SHARE = 0.5
GRABCUT_MAX_SHARE = 0.2
#: OpenCV GrabCut's smoothness weight (``gamma``) and sure pixels' terminal weight (``9 gamma``).
GAMMA = 50.0
LAMBDA = 9.0 * GAMMA
#: Data term of a colour neither model can produce (OpenCV: ``-ln 0``, an infinite link).
_NEVER = 1e30
#: OpenCV divides gamma by the float square root of 2 for diagonal links.
_SQRT2 = float(np.sqrt(np.float32(2.0)))


def model_terms(model: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(coefs (5,), means (5, 3), inverse covariances (5, 3, 3), 1/sqrt(det) (5,))`` of a
    (1, 65) OpenCV GrabCut model (weights, means, covariances row-major), computed as OpenCV
    does (cofactors); unused components (weight 0) get zeros."""
    m = np.ascontiguousarray(model, np.float64).reshape(-1)
    coefs, means, inv, scale, det, bad = _model_terms_kernel(m)
    if bad >= 0:
        raise ImageError(f"colour model component {bad} has a singular covariance (determinant {det:g})")
    return coefs, means, inv, scale


@njit(cache=True)
def _model_terms_kernel(m):
    k = m.size // 13
    coefs, means = m[:k].copy(), m[k:4 * k].copy().reshape(k, 3)
    inv = np.zeros((k, 3, 3))
    scale = np.zeros(k)
    for ci in range(k):
        if coefs[ci] <= 0:
            continue
        c = m[4 * k + 9 * ci:4 * k + 9 * ci + 9]
        det = (c[0] * (c[4] * c[8] - c[5] * c[7]) - c[1] * (c[3] * c[8] - c[5] * c[6])
               + c[2] * (c[3] * c[7] - c[4] * c[6]))
        if not det > 2.220446049250313e-16:
            return coefs, means, inv, scale, det, ci
        r = 1.0 / det
        inv[ci, 0, 0] = (c[4] * c[8] - c[5] * c[7]) * r
        inv[ci, 1, 0] = -(c[3] * c[8] - c[5] * c[6]) * r
        inv[ci, 2, 0] = (c[3] * c[7] - c[4] * c[6]) * r
        inv[ci, 0, 1] = -(c[1] * c[8] - c[2] * c[7]) * r
        inv[ci, 1, 1] = (c[0] * c[8] - c[2] * c[6]) * r
        inv[ci, 2, 1] = -(c[0] * c[7] - c[1] * c[6]) * r
        inv[ci, 0, 2] = (c[1] * c[5] - c[2] * c[4]) * r
        inv[ci, 1, 2] = -(c[0] * c[5] - c[2] * c[3]) * r
        inv[ci, 2, 2] = (c[0] * c[4] - c[1] * c[3]) * r
        scale[ci] = 1.0 / np.sqrt(det)
    return coefs, means, inv, scale, 0.0, -1


@njit(cache=True)
def _beta(img):
    """OpenCV GrabCut's beta: 1 / (2 mean squared colour difference of 8-neighbours) (the sum
    in integers: exact, as OpenCV's double sum is for any image this size)."""
    h, w = img.shape[0], img.shape[1]
    total = 0
    for y in range(h):
        for x in range(1, w):  # left
            for c in range(3):
                d = np.int64(img[y, x, c]) - np.int64(img[y, x - 1, c])
                total += d * d
        if y == 0:
            continue
        for x in range(w):  # up
            for c in range(3):
                d = np.int64(img[y, x, c]) - np.int64(img[y - 1, x, c])
                total += d * d
        for x in range(1, w):  # up-left
            for c in range(3):
                d = np.int64(img[y, x, c]) - np.int64(img[y - 1, x - 1, c])
                total += d * d
        for x in range(w - 1):  # up-right
            for c in range(3):
                d = np.int64(img[y, x, c]) - np.int64(img[y - 1, x + 1, c])
                total += d * d
    if total == 0:
        return 0.0
    return 1.0 / (2.0 * float(total) / (4 * w * h - 3 * w - 3 * h + 2))


@njit(cache=True)
def _data_term(colour, coefs, means, inv, scale):
    """``-ln`` of the mixture density at ``colour`` without the (2 pi)^-3/2 factor."""
    p = 0.0
    for c in range(coefs.shape[0]):
        if coefs[c] <= 0:
            continue
        d0 = colour[0] - means[c, 0]
        d1 = colour[1] - means[c, 1]
        d2 = colour[2] - means[c, 2]
        mult = (d0 * (d0 * inv[c, 0, 0] + d1 * inv[c, 1, 0] + d2 * inv[c, 2, 0])
                + d1 * (d0 * inv[c, 0, 1] + d1 * inv[c, 1, 1] + d2 * inv[c, 2, 1])
                + d2 * (d0 * inv[c, 0, 2] + d1 * inv[c, 1, 2] + d2 * inv[c, 2, 2]))
        p += coefs[c] * scale[c] * np.exp(-0.5 * mult)
    if p <= 0.0:
        return _NEVER
    return -np.log(p)


@njit(cache=True)
def _learn_kernel(img, labels, bg_coefs, bg_means, bg_inv, bg_scale, fg_coefs, fg_means, fg_inv, fg_scale,
                  out):
    """OpenCV GrabCut's assignGMMsComponents + learnGMMs: each pixel to its side's most likely
    component (density without the weight), then weights, means and covariances of the
    components from their pixels (0.01 added to a covariance's diagonal whose determinant is
    <= 1e-6). Writes the (2, 65) models [background, plant] into ``out``; returns the fewest
    samples of a side (0: a side without pixels)."""
    k = bg_coefs.shape[0]
    sums = np.zeros((2, k, 3))
    prods = np.zeros((2, k, 3, 3))
    counts = np.zeros((2, k), np.int64)
    h, w = labels.shape
    colour = np.empty(3)
    for y in range(h):
        for x in range(w):
            side = 1 if labels[y, x] == 1 or labels[y, x] == 3 else 0
            for c in range(3):
                colour[c] = float(img[y, x, c])
            best, top = 0, 0.0
            for ci in range(k):
                if side == 0:
                    coef, mean, inv, scale = bg_coefs[ci], bg_means[ci], bg_inv[ci], bg_scale[ci]
                else:
                    coef, mean, inv, scale = fg_coefs[ci], fg_means[ci], fg_inv[ci], fg_scale[ci]
                if coef <= 0:
                    continue
                d0, d1, d2 = colour[0] - mean[0], colour[1] - mean[1], colour[2] - mean[2]
                mult = (d0 * (d0 * inv[0, 0] + d1 * inv[1, 0] + d2 * inv[2, 0])
                        + d1 * (d0 * inv[0, 1] + d1 * inv[1, 1] + d2 * inv[2, 1])
                        + d2 * (d0 * inv[0, 2] + d1 * inv[1, 2] + d2 * inv[2, 2]))
                p = scale * np.exp(-0.5 * mult)
                if p > top:
                    best, top = ci, p
            counts[side, best] += 1
            for a in range(3):
                sums[side, best, a] += colour[a]
                for b in range(3):
                    prods[side, best, a, b] += colour[a] * colour[b]
    fewest = counts[0].sum()
    if counts[1].sum() < fewest:
        fewest = counts[1].sum()
    out[:] = 0.0
    for side in range(2):
        total = counts[side].sum()
        for ci in range(k):
            n = counts[side, ci]
            if n == 0 or total == 0:
                continue
            out[side, ci] = n / total
            m = sums[side, ci] / n
            cov = prods[side, ci] / n - np.outer(m, m)
            dtrm = (cov[0, 0] * (cov[1, 1] * cov[2, 2] - cov[1, 2] * cov[2, 1])
                    - cov[0, 1] * (cov[1, 0] * cov[2, 2] - cov[1, 2] * cov[2, 0])
                    + cov[0, 2] * (cov[1, 0] * cov[2, 1] - cov[1, 1] * cov[2, 0]))
            if dtrm <= 1e-6:
                for a in range(3):
                    cov[a, a] += 0.01
            out[side, k + 3 * ci:k + 3 * ci + 3] = m
            out[side, 4 * k + 9 * ci:4 * k + 9 * ci + 9] = cov.ravel()
    return fewest


def learn_models(image_bgr: np.ndarray, labels: np.ndarray, background_model: np.ndarray,
                 plant_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One GrabCut learning step (OpenCV's, exactly): the models of the pixels of each side of
    ``labels`` (uint8 (H, W) GrabCut labels), each pixel in the component of its side's current
    model (``background_model``, ``plant_model``: (1, 65) float64) it fits best. Returns the new
    ``(background_model, plant_model)``; a side without pixels gets all weights 0 (a density
    of 0 everywhere: its data term is infinite, as in OpenCV)."""
    img = np.ascontiguousarray(image_bgr)
    out = np.zeros((2, np.asarray(background_model).size))
    _learn_kernel(img, np.ascontiguousarray(labels), *model_terms(background_model), *model_terms(plant_model), out)
    return out[:1].copy(), out[1:].copy()


#: The 8 neighbour offsets (dy, dx); direction k's opposite is (k + 4) % 8. The first 4 are
#: OpenCV's left, up-left, up, up-right.
_DY = np.array([0, -1, -1, -1, 0, 1, 1, 1], np.int64)
_DX = np.array([-1, -1, 0, 1, 1, 1, 0, -1], np.int64)


@njit(cache=True)
def _build_graph(img, labels, bg_terms, fg_terms, gamma, beta, dy, dx):
    """The graph of the undecided pixels: ``(pixel (n, 2) [y, x], neighbour (n, 8) node or
    -1, capacity (n, 8) towards that neighbour, source (n,), sink (n,))`` with the terminal
    links reduced so that one of source/sink is 0 (the flow straight through a pixel)."""
    h, w = labels.shape
    node = np.full((h, w), -1, np.int64)
    n = 0
    for y in range(h):
        for x in range(w):
            if labels[y, x] >= 2:
                node[y, x] = n
                n += 1
    pixel = np.empty((n, 2), np.int64)
    nb = np.full((n, 8), -1, np.int64)
    cap = np.zeros((n, 8))
    source = np.zeros(n)
    sink = np.zeros(n)
    bg_coefs, bg_means, bg_inv, bg_scale = bg_terms
    fg_coefs, fg_means, fg_inv, fg_scale = fg_terms
    colour = np.empty(3)
    diag = gamma / _SQRT2
    for y in range(h):
        for x in range(w):
            p = node[y, x]
            if p < 0:
                continue
            pixel[p, 0], pixel[p, 1] = y, x
            for c in range(3):
                colour[c] = float(img[y, x, c])
            to_src = _data_term(colour, bg_coefs, bg_means, bg_inv, bg_scale)  # OpenCV's fromSource
            to_snk = _data_term(colour, fg_coefs, fg_means, fg_inv, fg_scale)  # and toSink
            for k in range(8):
                yy, xx = y + dy[k], x + dx[k]
                if yy < 0 or yy >= h or xx < 0 or xx >= w:
                    continue
                q = node[yy, xx]
                if q >= 0 and k >= 4:
                    continue  # a link between two undecided pixels: made from the later one
                d2 = 0.0
                for c in range(3):
                    d = colour[c] - float(img[yy, xx, c])
                    d2 += d * d
                wgt = (gamma if dy[k] == 0 or dx[k] == 0 else diag) * np.exp(-beta * d2)
                if q >= 0:
                    nb[p, k], cap[p, k] = q, wgt
                    nb[q, k + 4], cap[q, k + 4] = p, wgt
                elif labels[yy, xx] == 1:  # a sure plant neighbour: on the source side
                    to_src += wgt
                else:
                    to_snk += wgt
            both = min(to_src, to_snk)
            source[p], sink[p] = to_src - both, to_snk - both
    return pixel, nb, cap, source, sink


@njit(cache=True)
def _fix_decided(nb, cap, source, sink):
    """Settle the nodes whose terminal link outweighs all their neighbour links together
    (they lie on that side in every minimum cut): a settled node's links to its neighbours
    join their terminal links, which may settle them in turn. Returns (n,) int8: 1 = plant
    (source) side, -1 = background (sink) side, 0 = left to the max-flow; the settled nodes
    are cut out of ``nb``."""
    n = nb.shape[0]
    side = np.zeros(n, np.int8)
    links = np.zeros(n)
    for p in range(n):
        for k in range(8):
            if nb[p, k] >= 0:
                links[p] += cap[p, k]
    queue = np.arange(n)
    queued = np.ones(n, np.bool_)
    stack = n
    while stack > 0:
        stack -= 1
        p = queue[stack]
        queued[p] = False
        if source[p] > links[p]:
            s = 1
        elif sink[p] > links[p]:
            s = -1
        else:
            continue
        side[p] = s
        for k in range(8):
            q = nb[p, k]
            if q < 0:
                continue
            o = (k + 4) % 8
            if s > 0:
                source[q] += cap[q, o]  # (symmetric links: cap[p, k] == cap[q, o] until the flow)
            else:
                sink[q] += cap[q, o]
            both = min(source[q], sink[q])
            source[q] -= both
            sink[q] -= both
            links[q] = max(links[q] - cap[q, o], 0.0)  # (no rounding below zero: an isolated node is a tie)
            nb[q, o] = -1
            nb[p, k] = -1
            if not queued[q]:
                queued[q] = True
                queue[stack] = q
                stack += 1
    return side


#: Parent codes of the search trees besides a direction 0..7 to the parent node.
_TERMINAL = 8
_ORPHAN = 9
_NONE = -1


@njit(cache=True)
def _origin_ok(p, nb, parent_dir):
    """Whether ``p``'s parent chain reaches its terminal (no orphan on the way)."""
    u = p
    while True:
        d = parent_dir[u]
        if d == _TERMINAL:
            return True
        if d < 0 or d == _ORPHAN:
            return False
        u = nb[u, d]


@njit(cache=True)
def _max_flow_source_side(nb, cap, source, sink):
    """Boykov-Kolmogorov max-flow from the source to the sink of the graph :func:`_build_graph`
    gives (capacities updated in place): a source tree and a sink tree grow until they touch,
    the path's bottleneck is pushed, the orphaned subtrees are adopted or freed. Returns (n,)
    bool, the source tree at the end: the nodes the source still reaches in the residual
    graph (the plant side of the minimum cut)."""
    n = nb.shape[0]
    tree = np.zeros(n, np.int8)
    parent_dir = np.full(n, _NONE, np.int64)
    queue = np.empty(n + 1, np.int64)
    in_queue = np.zeros(n, np.bool_)
    qh, qt, size = 0, 0, n + 1
    orphans = np.empty(n, np.int64)
    n_orphans = 0
    for p in range(n):
        if source[p] > 0:
            tree[p], parent_dir[p] = 1, _TERMINAL
        elif sink[p] > 0:
            tree[p], parent_dir[p] = 2, _TERMINAL
        else:
            continue
        queue[qt] = p
        qt = (qt + 1) % size
        in_queue[p] = True
    while qh != qt:
        p = queue[qh]
        qh = (qh + 1) % size
        in_queue[p] = False
        k = 0
        while k < 8 and tree[p] != 0:
            q = nb[p, k]
            if q < 0:
                k += 1
                continue
            o = (k + 4) % 8
            res = cap[p, k] if tree[p] == 1 else cap[q, o]
            if res <= 0:
                k += 1
                continue
            if tree[q] == 0:
                tree[q], parent_dir[q] = tree[p], o
                if not in_queue[q]:
                    queue[qt] = q
                    qt = (qt + 1) % size
                    in_queue[q] = True
                k += 1
                continue
            if tree[q] == tree[p]:
                k += 1
                continue
            # a path: source ... s -> t ... sink
            if tree[p] == 1:
                s, t, sk = p, q, k
            else:
                s, t, sk = q, p, o
            f = cap[s, sk]
            u = s
            while parent_dir[u] != _TERMINAL:
                d = parent_dir[u]
                v = nb[u, d]
                f = min(f, cap[v, (d + 4) % 8])
                u = v
            f = min(f, source[u])
            u = t
            while parent_dir[u] != _TERMINAL:
                d = parent_dir[u]
                f = min(f, cap[u, d])
                u = nb[u, d]
            f = min(f, sink[u])
            cap[s, sk] -= f
            cap[t, (sk + 4) % 8] += f
            u = s
            while parent_dir[u] != _TERMINAL:
                d = parent_dir[u]
                v = nb[u, d]
                cap[v, (d + 4) % 8] -= f
                cap[u, d] += f
                if cap[v, (d + 4) % 8] <= 0:
                    parent_dir[u] = _ORPHAN
                    orphans[n_orphans] = u
                    n_orphans += 1
                u = v
            source[u] -= f  # (u: the path's first node, its link to the source)
            if source[u] <= 0:
                parent_dir[u] = _ORPHAN
                orphans[n_orphans] = u
                n_orphans += 1
            u = t
            while parent_dir[u] != _TERMINAL:
                d = parent_dir[u]
                v = nb[u, d]
                cap[u, d] -= f
                cap[v, (d + 4) % 8] += f
                if cap[u, d] <= 0:
                    parent_dir[u] = _ORPHAN
                    orphans[n_orphans] = u
                    n_orphans += 1
                u = v
            sink[u] -= f
            if sink[u] <= 0:
                parent_dir[u] = _ORPHAN
                orphans[n_orphans] = u
                n_orphans += 1
            # adoption
            while n_orphans > 0:
                n_orphans -= 1
                a = orphans[n_orphans]
                ta = tree[a]
                found = -1
                if ta == 1 and source[a] > 0 or ta == 2 and sink[a] > 0:
                    found = _TERMINAL
                else:
                    for j in range(8):
                        b = nb[a, j]
                        if b < 0 or tree[b] != ta:
                            continue
                        r = cap[b, (j + 4) % 8] if ta == 1 else cap[a, j]
                        if r > 0 and _origin_ok(b, nb, parent_dir):
                            found = j
                            break
                if found >= 0:
                    parent_dir[a] = found
                    continue
                for j in range(8):
                    b = nb[a, j]
                    if b < 0 or tree[b] != ta:
                        continue
                    r = cap[b, (j + 4) % 8] if ta == 1 else cap[a, j]
                    if r > 0 and not in_queue[b]:
                        queue[qt] = b
                        qt = (qt + 1) % size
                        in_queue[b] = True
                    if parent_dir[b] == (j + 4) % 8:
                        parent_dir[b] = _ORPHAN
                        orphans[n_orphans] = b
                        n_orphans += 1
                tree[a] = 0
                parent_dir[a] = _NONE
    reached = np.zeros(n, np.bool_)
    for p in range(n):
        reached[p] = tree[p] == 1
    return reached


def frozen_model_cut(image_bgr: np.ndarray, labels: np.ndarray, background_model: np.ndarray,
                     plant_model: np.ndarray) -> np.ndarray:
    """OpenCV's ``grabCut(image, labels, None, background_model, plant_model, 1,
    GC_EVAL_FREEZE_MODEL)`` on the undecided pixels only (see the module docstring).

    Args:
        image_bgr: (H, W, 3) uint8 colour image.
        labels: (H, W) uint8 GrabCut labels (0..3); not modified.
        background_model, plant_model: (1, 65) float64 OpenCV GrabCut models.

    Returns:
        New (H, W) uint8 labels: the sure pixels as given, each undecided one
        ``GC_PR_FGD`` (3) or ``GC_PR_BGD`` (2).
    """
    img = np.ascontiguousarray(image_bgr)
    out = np.ascontiguousarray(labels, dtype=np.uint8).copy()
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or out.shape != img.shape[:2]:
        raise ImageError(f"the cut needs a uint8 (H, W, 3) image and (H, W) labels, got {img.dtype} "
                         f"{img.shape} and {out.shape}")
    if out.size and out.max() > 3:
        raise ImageError("GrabCut labels must be 0 (background), 1 (plant), 2 (probable background) "
                         "or 3 (probable plant)")
    undecided = int(np.count_nonzero(out >= 2))
    if undecided == 0:
        return out
    if undecided > FROZEN_CUT_MAX_SHARE * out.size:
        try:
            cv2.grabCut(img, out, None, np.array(background_model, np.float64).reshape(1, -1),
                        np.array(plant_model, np.float64).reshape(1, -1), 1, cv2.GC_EVAL_FREEZE_MODEL)
        except cv2.error as exc:
            raise ImageError(f"GrabCut failed on this seed: {str(exc).strip().splitlines()[-1]}") from None
        return out
    pixel, nb, cap, source, sink = _build_graph(img, out, model_terms(background_model),
                                                 model_terms(plant_model), GAMMA, _beta(img), _DY, _DX)
    side = _fix_decided(nb, cap, source, sink)
    plant = (side > 0) | ((side == 0) & _max_flow_source_side(nb, cap, source, sink))
    out[pixel[:, 0], pixel[:, 1]] = np.where(plant, 3, 2).astype(np.uint8)
    return out
