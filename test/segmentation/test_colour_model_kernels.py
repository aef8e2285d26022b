"""The numba kernels of the colour models (canopy_stereo.segmentation.colour_model) against naive
numpy references."""
from __future__ import annotations

import numpy as np

from canopy_stereo.segmentation.colour_model import (
    COV_FLOOR,
    ColourGMM,
    _component_log_densities,
    _gmm_from_responsibilities,
    _lloyd,
    fit_colour_gmm,
)


def _naive_log_densities(x, gmm):
    out = np.full((len(x), len(gmm.weights)), -np.inf)
    for k, (w, mu, cov) in enumerate(zip(gmm.weights, gmm.means, gmm.covariances)):
        if w > 0:
            d = x - mu
            maha = ((d @ np.linalg.inv(cov)) * d).sum(axis=1)
            out[:, k] = np.log(w) - 0.5 * (maha + np.linalg.slogdet(cov)[1] + 3.0 * np.log(2.0 * np.pi))
    return out


def _colours(rng, n=3000):
    centres = np.array([[40.0, 150.0, 60.0], [120.0, 110.0, 100.0], [200.0, 60.0, 30.0]])
    x = centres[rng.integers(0, 3, n)] + rng.normal(0.0, [[6.0, 10.0, 4.0]], (n, 3))
    return np.clip(np.rint(x), 0, 255)


def test_log_densities_and_moments_match_numpy(rng):
    x = _colours(rng)
    resp = rng.dirichlet(np.ones(5), len(x))
    resp[:, 4] = 0.0  # an unused component
    weights, means, covs = _gmm_from_responsibilities(x, resp)
    n = resp.sum(axis=0)
    for k in range(4):
        mean = resp[:, k] @ x / n[k]
        d = x - mean
        assert np.allclose(means[k], mean)
        assert np.allclose(covs[k], (resp[:, k, None] * d).T @ d / n[k] + np.eye(3) * COV_FLOOR)
    assert weights[4] == 0 and np.isclose(weights.sum(), 1.0)
    gmm = ColourGMM(weights, means, covs)
    ours, naive = _component_log_densities(x, gmm), _naive_log_densities(x, gmm)
    assert np.array_equal(np.isinf(ours), np.isinf(naive))
    assert np.allclose(ours[:, :4], naive[:, :4], rtol=1e-10, atol=1e-9)


def test_lloyd_reaches_a_fixed_point_and_the_fit_finds_the_clusters(rng):
    x = _colours(rng)
    lab = _lloyd(x, x[[0, 1, 2, 3, 4]].copy(), 100)
    centres = np.array([x[lab == j].mean(axis=0) for j in range(5)])
    nearest = ((x[:, None, :] - centres[None]) ** 2).sum(-1).argmin(axis=1)
    assert np.array_equal(nearest, lab)  # every point at its nearest centre: converged
    gmm = fit_colour_gmm(x, components=3, max_samples=2000, iterations=5)
    found = sorted(map(tuple, np.rint(gmm.means).astype(int)))
    assert np.allclose(found, [[40, 150, 60], [120, 110, 100], [200, 60, 30]], atol=2)
