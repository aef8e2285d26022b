"""ELAS parameters: the reference table as a dataclass, the two presets, validation.

Units: disparities and sizes in pixels of the input images; ``beta``, ``gamma``,
``sigma`` are the dimensionless constants of the prior (Geiger et al., ACCV 2010).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from canopy_stereo.errors import CanopyStereoError

#: Smallest disparity range a support point needs (the original rejects
#: candidates with fewer than 11 disparities inside the image).
MIN_SUPPORT_DISPARITIES = 11


@dataclass(frozen=True)
class ElasParams:
    """Every parameter of the ELAS reference table, plus this package's extras.

    Attributes (reference table):
        disp_min, disp_max: disparity search range in pixels (``u_right = u_left - d``).
        support_threshold: a support candidate is kept only if its best cost is below
            this fraction of its second-best cost (uniqueness ratio).
        support_texture: minimum descriptor texture of a support candidate.
        candidate_stepsize: spacing in pixels of the support-candidate grid.
        incon_window_size, incon_threshold, incon_min_support: a support point needs
            ``incon_min_support`` points (itself included) within ``incon_window_size``
            candidate cells whose disparity differs by at most ``incon_threshold``.
        add_corners: add the 4 image corners as support points and extrapolate the
            gap interpolation to the image borders.
        grid_size: cell size in pixels of the disparity grid.
        beta, gamma, sigma, sradius: prior
            ``P[D] = int((ln g - ln(g + exp(-D^2 / 2 s^2))) / beta)``
            and plane search radius ``max(ceil(sigma * sradius), 2)``.
        match_texture: minimum descriptor texture of a densely matched pixel.
        lr_threshold: left-right consistency tolerance in pixels.
        speckle_sim_threshold, speckle_size: 4-connected segments of chained
            disparities differing by at most the threshold and smaller than
            ``speckle_size`` pixels are removed.
        ipol_gap_width: longest run of invalid pixels that gap interpolation fills.
        filter_median: 7-tap separable median filter on the result.
        filter_adaptive_mean: 8-tap separable adaptive mean filter on the result.
        postprocess_only_left: skip small-segment removal, interpolation and filters
            on the right map.
        subsampling: match only every second row and column (half-size output,
            disparities still in full-resolution pixels).

    Extras (not in the original):
        subpixel: refine each matched disparity by a parabola through the matching
            cost (descriptor SAD) at ``d - 1, d, d + 1``, where ``d`` is also a local
            minimum of the SAD (elsewhere the integer value stays).
        adaptive_mean_weights: ``"step"`` (the original as compiled: weight 4 for
            ``|dd| < 2``, 2 for ``2 <= |dd| < 8``, else 0) or ``"linear"``
            (the original's stated intent, ``max(0, 4 - |dd|)``).
    """

    disp_min: int = 0
    disp_max: int = 255
    support_threshold: float = 0.85
    support_texture: int = 10
    candidate_stepsize: int = 5
    incon_window_size: int = 5
    incon_threshold: int = 5
    incon_min_support: int = 5
    add_corners: bool = False
    grid_size: int = 20
    beta: float = 0.02
    gamma: float = 3.0
    sigma: float = 1.0
    sradius: float = 2.0
    match_texture: int = 1
    lr_threshold: int = 2
    speckle_sim_threshold: float = 1.0
    speckle_size: int = 200
    ipol_gap_width: int = 3
    filter_median: bool = False
    filter_adaptive_mean: bool = True
    postprocess_only_left: bool = True
    subsampling: bool = False
    subpixel: bool = False
    adaptive_mean_weights: str = "step"

    def replace(self, **changes) -> ElasParams:
        """A copy with ``changes`` applied (unknown names raise :class:`CanopyStereoError`)."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise CanopyStereoError(
                f"unknown ELAS parameter(s) {', '.join(unknown)}; "
                f"known: {', '.join(sorted(known))}")
        return replace(self, **changes)

    def as_dict(self) -> dict:
        return asdict(self)

    def validate(self) -> ElasParams:
        """Return ``self`` or raise :class:`CanopyStereoError` naming the bad value."""
        def need(ok: bool, msg: str) -> None:
            if not ok:
                raise CanopyStereoError(f"ELAS: {msg}")

        need(self.disp_min >= 0, f"disp_min must be >= 0, got {self.disp_min}")
        need(self.disp_max >= self.disp_min,
             f"disp_max ({self.disp_max}) must not be smaller than disp_min ({self.disp_min})")
        need(self.disp_max - self.disp_min + 1 >= MIN_SUPPORT_DISPARITIES,
             f"the disparity range [{self.disp_min}, {self.disp_max}] must hold at least "
             f"{MIN_SUPPORT_DISPARITIES} disparities (support points need them)")
        need(self.disp_max <= 32000, f"disp_max must be <= 32000, got {self.disp_max}")
        need(0.0 < self.support_threshold <= 1.0,
             f"support_threshold must be in (0, 1], got {self.support_threshold}")
        need(self.candidate_stepsize >= 1, "candidate_stepsize must be >= 1")
        need(self.incon_window_size >= 0, "incon_window_size must be >= 0")
        need(self.grid_size >= 1, "grid_size must be >= 1")
        need(self.beta > 0, f"beta must be > 0, got {self.beta}")
        need(self.gamma > 0, f"gamma must be > 0, got {self.gamma}")
        need(self.sigma > 0, f"sigma must be > 0, got {self.sigma}")
        need(self.sradius >= 0, f"sradius must be >= 0, got {self.sradius}")
        need(self.lr_threshold >= 0, "lr_threshold must be >= 0")
        need(self.speckle_size >= 0, "speckle_size must be >= 0")
        need(self.ipol_gap_width >= 0, "ipol_gap_width must be >= 0")
        need(self.adaptive_mean_weights in ("step", "linear"),
             "adaptive_mean_weights must be 'step' or 'linear', "
             f"got {self.adaptive_mean_weights!r}")
        return self


#: The preset used when none is named (the original's default, tuned for robotics images).
DEFAULT_PRESET = "robotics"

#: The original's two presets (reference table of ``elas.md``).
PRESETS: dict[str, ElasParams] = {
    "robotics": ElasParams(),
    "middlebury": ElasParams(
        support_threshold=0.95, add_corners=True, gamma=5.0, sradius=3.0, match_texture=0,
        ipol_gap_width=5000, filter_median=True, filter_adaptive_mean=False,
        postprocess_only_left=False),
}


def make_params(preset: str = DEFAULT_PRESET, **params) -> ElasParams:
    """Validated :class:`ElasParams` from a preset name and keyword overrides."""
    base = PRESETS.get(str(preset).lower())
    if base is None:
        raise CanopyStereoError(
            f"unknown ELAS preset {preset!r}; choose one of {', '.join(PRESETS)}")
    return base.replace(**params).validate()
