"""The frozen-model graph cut on the undecided pixels only (canopy_stereo.segmentation.frozen_cut)
against OpenCV's own ``grabCut(..., GC_EVAL_FREEZE_MODEL)`` over the whole image."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from canopy_stereo.errors import ImageError
from canopy_stereo.segmentation.auto import VIDEO_SEEDER, seed_labels
from canopy_stereo.segmentation.colour_model import fit_colour_gmm
from canopy_stereo.segmentation.frozen_cut import GAMMA, frozen_model_cut, model_terms
from canopy_stereo.segmentation.grabcut import GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD, GRABCUT_RNG_SEED


def _grabcut_energy(img, seed, labels, background_model, plant_model) -> float:
    """OpenCV GrabCut's energy of ``labels`` (data terms of the undecided pixels of ``seed`` plus
    the 8-neighbour smoothness terms), computed naively."""
    img = img.astype(np.float64)
    h, w = seed.shape

    def minus_log_density(model):
        coefs, means, inv, scale = model_terms(model)
        p = np.zeros((h, w))
        for c in np.nonzero(coefs > 0)[0]:
            d = img - means[c]
            p += coefs[c] * scale[c] * np.exp(-0.5 * np.einsum("hwi,ij,hwj->hw", d, inv[c], d))
        return -np.log(p)

    plant = (labels == GC_FGD) | (labels == GC_PR_FGD)
    energy = np.where(plant, minus_log_density(plant_model), minus_log_density(background_model))[seed >= 2].sum()
    pad = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    pad_plant = np.pad(plant, 1, mode="edge")
    pairs = []
    for dy, dx, weight in ((0, -1, GAMMA), (-1, -1, GAMMA / np.sqrt(np.float32(2))), (-1, 0, GAMMA),
                           (-1, 1, GAMMA / np.sqrt(np.float32(2)))):
        inside = np.zeros((h, w), bool)
        inside[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)] = True
        other = pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
        d2 = ((img - other) ** 2).sum(-1)
        pairs.append((inside, d2, weight, pad_plant[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]))
    beta = 1.0 / (2.0 * sum(d2[inside].sum() for inside, d2, _, _ in pairs) / (4 * w * h - 3 * w - 3 * h + 2))
    for inside, d2, weight, other_plant in pairs:
        energy += (weight * np.exp(-beta * d2) * (inside & (plant != other_plant))).sum()
    return float(energy)


def _scene(seed: int):
    """A leafy synthetic frame at the propagated frames' size (160x120), its automatic seed and
    colour models fitted to a rough plant mask, as MaskPropagator makes them."""
    from canopy_stereo.sim.stereo_pair import synthetic_pair

    left = synthetic_pair(160, 120, plane=(0.0, 0.0, 20.0), texture="blocks", colour=True, seed=seed)[0]
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:120, :160]
    plant = np.zeros((120, 160), bool)
    for _ in range(6):  # green leaves over the textured background
        cy, cx, ry, rx = rng.uniform(20, 100), rng.uniform(30, 130), rng.uniform(8, 20), rng.uniform(5, 14)
        plant |= ((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 < 1
    colour = np.array([40, 150, 60]) + rng.normal(0, 12, (120, 160, 3))
    img = np.where(plant[..., None], colour, left).clip(0, 255).astype(np.uint8)
    img = cv2.GaussianBlur(img, (3, 3), 0)
    seed_lab = seed_labels(img, VIDEO_SEEDER.replace(scale=1.0))
    pixels = img.reshape(-1, 3)
    plant_gmm = fit_colour_gmm(pixels[plant.ravel()], max_samples=2000, iterations=3)
    background_gmm = fit_colour_gmm(pixels[~plant.ravel()], max_samples=2000, iterations=3)
    return img, seed_lab, background_gmm.grabcut_model(), plant_gmm.grabcut_model()


def _opencv(img, seed, background_model, plant_model):
    labels = seed.copy()
    cv2.grabCut(img, labels, None, background_model.copy(), plant_model.copy(), 1, cv2.GC_EVAL_FREEZE_MODEL)
    return labels


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_cut_is_opencvs_minimum_cut(seed):
    """Automatic seeds of leafy frames: the same labels as OpenCV's GrabCut (the minimum is
    unique but for ties: the energy must be OpenCV's, and the labels all but a few)."""
    img, seed_lab, bg, fg = _scene(seed)
    undecided = seed_lab >= 2
    assert undecided.sum() > 200 and (seed_lab < 2).sum() > 200  # a real cut to make
    ours = frozen_model_cut(img, seed_lab, bg, fg)
    reference = _opencv(img, seed_lab, bg, fg)
    assert np.array_equal(ours[~undecided], seed_lab[~undecided])
    assert set(np.unique(ours[undecided])) <= {GC_PR_BGD, GC_PR_FGD}
    assert _grabcut_energy(img, seed_lab, ours, bg, fg) == pytest.approx(
        _grabcut_energy(img, seed_lab, reference, bg, fg), rel=1e-9)
    assert (ours != reference).sum() <= 0.002 * undecided.sum()


@pytest.mark.parametrize("undecided", [0.3, 0.7, 0.97])
def test_random_seeds_everywhere_undecided(undecided):
    """Seeds with undecided pixels scattered over the whole image (long max-flow paths, search
    trees cut and re-adopted, few settled pixels): still OpenCV's cut."""
    img, _, bg, fg = _scene(3)
    rng = np.random.default_rng(3)
    sure = (1.0 - undecided) / 2
    seed_lab = rng.choice(np.array([GC_BGD, GC_FGD, GC_PR_BGD, GC_PR_FGD], np.uint8), size=img.shape[:2],
                          p=[sure, sure, undecided / 2, undecided / 2])
    ours = frozen_model_cut(img, seed_lab, bg, fg)
    reference = _opencv(img, seed_lab, bg, fg)
    assert _grabcut_energy(img, seed_lab, ours, bg, fg) == pytest.approx(
        _grabcut_energy(img, seed_lab, reference, bg, fg), rel=1e-9)
    assert (ours != reference).sum() <= 0.002 * (seed_lab >= 2).sum()


def test_bad_inputs_are_named():
    img, seed_lab, bg, fg = _scene(0)
    with pytest.raises(ImageError, match="labels must be"):
        frozen_model_cut(img, np.full(seed_lab.shape, 7, np.uint8), bg, fg)
    with pytest.raises(ImageError, match="uint8"):
        frozen_model_cut(img[..., 0], seed_lab, bg, fg)
    singular = fg.copy()
    singular[0, 20:29] = 0.0  # component 0: a zero covariance
    with pytest.raises(ImageError, match="singular covariance"):
        frozen_model_cut(img, seed_lab, bg, singular)


@pytest.mark.parametrize("seed", [0, 1])
def test_grabcut_iterations_are_opencvs(seed):
    """grabcut_labels (OpenCV's k-means start, then learn_models + the cut on the undecided pixels
    per iteration) against OpenCV's own 3 iterations from the same random state (the product's
    GRABCUT_RNG_SEED, whatever the thread's generator was at): the same labels."""
    from canopy_stereo.segmentation.grabcut import grabcut_labels

    img, seed_lab, _, _ = _scene(seed)
    cv2.setRNGSeed(GRABCUT_RNG_SEED)
    reference = seed_lab.copy()
    cv2.grabCut(img, reference, None, np.zeros((1, 65)), np.zeros((1, 65)), 3, cv2.GC_INIT_WITH_MASK)
    cv2.randu(np.zeros(16), 0, 1)  # another state: grabcut_labels starts from its own
    ours = grabcut_labels(img, seed_lab, iterations=3)
    assert (ours != reference).sum() <= 0.002 * (seed_lab >= 2).sum()
    assert ((ours == GC_PR_FGD) != (seed_lab == GC_PR_FGD)).any()  # the iterations changed something


def test_a_side_without_pixels_learns_an_empty_model_as_opencv_does():
    """When a GrabCut iteration leaves no pixel on one side, OpenCV's next model of that side has
    all weights 0 (density 0: an infinite data term) and its cut puts every undecided pixel on
    the other side; so do learn_models and the cut (no error)."""
    from canopy_stereo.segmentation.frozen_cut import learn_models

    img, seed_lab, bg, fg = _scene(0)
    no_plant = np.where(seed_lab == GC_FGD, GC_BGD, np.where(seed_lab == GC_PR_FGD, GC_PR_BGD, seed_lab))
    new_bg, new_fg = learn_models(img, no_plant.astype(np.uint8), bg, fg)
    assert not new_fg.any() and np.isclose(new_bg[0, :5].sum(), 1.0)
    ours = frozen_model_cut(img, seed_lab, new_bg, new_fg)
    assert np.array_equal(ours, _opencv(img, seed_lab, new_bg, new_fg))
    assert not (ours == GC_PR_FGD).any()


@pytest.mark.parametrize("share", [0.3, 0.6])
def test_seeds_mostly_undecided_go_to_opencv_with_the_same_result(share):
    """A rectangle seed of this share of the image (GrabCut's own interaction): grabcut_labels and
    the cut hand large undecided blobs to OpenCV (:data:`GRABCUT_MAX_SHARE`,
    :data:`FROZEN_CUT_MAX_SHARE`); the labels are OpenCV's either way."""
    from canopy_stereo.segmentation.grabcut import grabcut_labels

    img, _, bg, fg = _scene(1)
    h, w = img.shape[:2]
    side = np.sqrt(share)
    y0, x0 = int(h * (1 - side) / 2), int(w * (1 - side) / 2)
    seed_lab = np.full((h, w), GC_BGD, np.uint8)
    seed_lab[y0:h - y0, x0:w - x0] = GC_PR_FGD
    cv2.setRNGSeed(GRABCUT_RNG_SEED)
    reference = seed_lab.copy()
    cv2.grabCut(img, reference, None, np.zeros((1, 65)), np.zeros((1, 65)), 3, cv2.GC_INIT_WITH_MASK)
    assert (grabcut_labels(img, seed_lab, iterations=3) != reference).sum() <= 0.002 * (seed_lab >= 2).sum()
    ours = frozen_model_cut(img, seed_lab, bg, fg)
    assert (ours != _opencv(img, seed_lab, bg, fg)).sum() <= 0.002 * (seed_lab >= 2).sum()
