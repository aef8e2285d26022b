"""Camera side of the simulator: pixel sampling, lens distortion, image formation.

* Sub-pixel sample patterns for anti-aliasing (:func:`sample_pattern`); sample
  0 is always the pixel centre, whose ray gives the ground truth.
* Ideal (undistorted) sample positions for a camera with lens distortion
  (:func:`ideal_sample_map`), using the pipeline's own distortion model
  (:mod:`canopy_stereo.geometry.distortion`: OpenCV's model up to 12 terms or equidistant
  through the full intrinsics of ``P``), so a simulated distorted image is
  exactly what the reconstruction pipeline expects.
* Sensor response (:class:`CameraEffects`): exposure and per-camera gain,
  vignetting, gamma encoding, Gaussian noise and 8-bit quantisation.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache

import numpy as np

from canopy_stereo.errors import CanopyStereoError
from canopy_stereo.geometry.distortion import distort_pixels, undistort_pixels


def sample_pattern(supersample: int) -> tuple[np.ndarray, np.ndarray]:
    """Sub-pixel sample offsets (S, 2) in pixels and weights (S,) summing to 1.

    ``supersample`` 1: the pixel centre only. 2: quincunx, the centre (weight
    1/2) and the four pixel corners (1/8 each); the renderer traces the corner
    grid once for all pixels, so this costs 2 rays per pixel. ``n >= 3``: an
    ``n x n`` grid of equal weights; with ``n`` even the centre is added with
    weight 0 (traced for the ground truth, not shaded). Sample 0 is always the
    pixel centre, which gives the ground truth; with ``n = 2`` sample 1 is the
    top-left corner.
    """
    n = int(supersample)
    if n < 1 or n > 8:
        raise CanopyStereoError(f"supersample must be 1..8, got {supersample}")
    if n == 1:
        return np.zeros((1, 2)), np.ones(1)
    if n == 2:
        offsets = np.array([[0.0, 0.0], [-0.5, -0.5], [0.5, -0.5], [-0.5, 0.5], [0.5, 0.5]])
        return offsets, np.array([0.5, 0.125, 0.125, 0.125, 0.125])
    g = (np.arange(n) + 0.5) / n - 0.5
    gu, gv = np.meshgrid(g, g)
    grid = np.column_stack([gu.ravel(), gv.ravel()])
    centre = np.all(np.abs(grid) < 1e-12, axis=1)
    offsets = np.vstack([np.zeros((1, 2)), grid[~centre]])
    weights = np.full(len(offsets), 1.0 / len(grid))
    if not np.any(centre):
        weights[0] = 0.0
    return offsets, weights


def lattice_pattern(count: int = 16, generator: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """Rank-1 lattice sample pattern: offsets (count + 1, 2) in pixels and weights.

    Sample ``k`` of ``count`` sits at ``((k + 1/2) / count, ((generator k) mod count + 1/2) / count)
    - 1/2``: every sample has its own column AND its own row, so a nearly
    horizontal or vertical edge (a chessboard's) is resolved in ``count`` steps
    instead of ``sqrt(count)`` for an ``n x n`` grid with as many rays.
    ``generator`` must be coprime with ``count``. Sample 0 is the pixel centre
    with weight 0 (traced for the ground truth only), as in :func:`sample_pattern`.
    """
    import math

    n = int(count)
    if n < 2 or math.gcd(int(generator), n) != 1:
        raise CanopyStereoError(f"lattice_pattern needs count >= 2 and a generator coprime with it, "
                                f"got {count}, {generator}")
    k = np.arange(n)
    grid = np.column_stack([(k + 0.5) / n - 0.5, ((int(generator) * k) % n + 0.5) / n - 0.5])
    offsets = np.vstack([np.zeros((1, 2)), grid])
    weights = np.concatenate([[0.0], np.full(n, 1.0 / n)])
    return offsets, weights


def check_distortion(D, name: str, *, model: str | None = None) -> np.ndarray | None:
    """The coefficients of ``D`` for ``model`` (any model of
    :mod:`canopy_stereo.geometry.distortion`: OpenCV's up to 12 terms, or equidistant), or
    None when ``D`` is no distortion. Raises :class:`CanopyStereoError` naming ``name``
    for coefficients the model cannot have."""
    from canopy_stereo.errors import RigError
    from canopy_stereo.geometry.distortion import check_distortion as check_coefficients
    from canopy_stereo.geometry.distortion import distortion_is_identity

    try:
        d = check_coefficients(D, model, name)
    except RigError as exc:
        raise CanopyStereoError(str(exc)) from None
    return None if distortion_is_identity(d, model=model) else d


@lru_cache(maxsize=4)
def _ideal_map_cached(P_bytes, D_bytes, width, height, offsets_bytes, model):
    P = np.frombuffer(P_bytes).reshape(3, 4)
    D = np.frombuffer(D_bytes)
    offsets = np.frombuffer(offsets_bytes).reshape(-1, 2)
    vv, uu = np.mgrid[0:height, 0:width].astype(np.float64)
    xy = np.stack([uu[..., None] + offsets[:, 0], vv[..., None] + offsets[:, 1]], axis=-1)
    flat = xy.reshape(-1, 2)
    ideal = undistort_pixels(P, D, flat, model=model)
    back = distort_pixels(P, D, ideal, model=model)
    bad = ~(np.linalg.norm(back - flat, axis=1) < 1e-6)  # also catches NaN
    ideal[bad] = np.nan
    out = ideal.reshape(height, width, len(offsets), 2)
    out.flags.writeable = False
    return out


def ideal_sample_map(P, D, image_size, offsets, *, model: str | None = None) -> np.ndarray:
    """Ideal pixel (H, W, S, 2) of every distorted sample position ``(u, v) + offset``
    through the lens ``D`` of ``model`` (None = OpenCV's model).

    Samples whose undistortion does not converge (outside the lens model's
    invertible region) are NaN and render as empty. Cached per camera.
    """
    w, h = image_size
    return _ideal_map_cached(np.ascontiguousarray(P, np.float64).tobytes(),
                             np.ascontiguousarray(D, np.float64).tobytes(), int(w), int(h),
                             np.ascontiguousarray(offsets, np.float64).tobytes(), model)


@dataclass(frozen=True)
class CameraEffects:
    """Sensor response of the two cameras.

    Attributes:
        exposure: scale from scene radiance to linear sensor signal (both cameras).
        gain_left, gain_right: extra per-camera gain (an exposure/gain mismatch
            between the webcams when they differ).
        vignetting: relative brightness loss at the image corners; the
            signal is scaled by ``1 - vignetting * (r / r_corner)^2`` with ``r``
            the distance from the image centre.
        gamma: encoding gamma (``value = signal^(1/gamma)``).
        noise_sigma: standard deviation of additive Gaussian noise in 8-bit
            levels (DN), drawn per pixel and channel from the seed.
        white_balance_left, white_balance_right: per-camera (red, green, blue) gains on the
            linear signal (each webcam's own automatic white balance).
    """

    exposure: float = 1.3
    gain_left: float = 1.0
    gain_right: float = 0.93
    vignetting: float = 0.2
    gamma: float = 2.2
    noise_sigma: float = 1.0
    white_balance_left: tuple = (1.0, 1.0, 1.0)
    white_balance_right: tuple = (1.0, 1.0, 1.0)

    def __post_init__(self):
        if self.exposure <= 0 or self.gain_left <= 0 or self.gain_right <= 0 or self.gamma <= 0:
            raise CanopyStereoError("exposure, gains and gamma must be positive")
        for name in ("white_balance_left", "white_balance_right"):
            wb = tuple(float(g) for g in getattr(self, name))
            if len(wb) != 3 or not all(np.isfinite(g) and g > 0 for g in wb):
                raise CanopyStereoError(f"{name} must be three positive (red, green, blue) gains, got {wb}")
            object.__setattr__(self, name, wb)
        if not 0 <= self.vignetting < 1:
            raise CanopyStereoError(f"vignetting must be in [0, 1), got {self.vignetting}")
        if self.noise_sigma < 0:
            raise CanopyStereoError(f"noise_sigma must be >= 0, got {self.noise_sigma}")

    def as_dict(self) -> dict:
        return asdict(self)

    def expose(self, radiance: np.ndarray, camera: int,
               rng: np.random.Generator | None) -> np.ndarray:
        """uint8 BGR image (H, W, 3) from linear RGB ``radiance`` (H, W, 3).

        ``camera`` 0 is the left, 1 the right camera; ``rng`` draws the noise
        (required when ``noise_sigma > 0``).
        """
        h, w = radiance.shape[:2]
        gain = self.exposure * (self.gain_left if camera == 0 else self.gain_right)
        signal = radiance.astype(np.float64) * gain
        balance = self.white_balance_left if camera == 0 else self.white_balance_right
        if balance != (1.0, 1.0, 1.0):
            signal *= np.asarray(balance)
        if self.vignetting > 0:
            vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
            r2 = (uu - (w - 1) / 2.0) ** 2 + (vv - (h - 1) / 2.0) ** 2
            signal *= (1.0 - self.vignetting * r2 / r2.max())[..., None]
        value = 255.0 * np.clip(signal, 0.0, 1.0) ** (1.0 / self.gamma)
        if self.noise_sigma > 0:
            value += rng.normal(0.0, self.noise_sigma, value.shape)
        return np.clip(np.rint(value), 0, 255).astype(np.uint8)[..., ::-1].copy()


#: Ideal cameras: equal gains, no vignetting, no noise (for photometric checks).
CLEAN = CameraEffects(gain_right=1.0, vignetting=0.0, noise_sigma=0.0)
