"""Name -> matcher registry: everything the package knows about a dense matcher.

Each matcher is a :class:`MatcherSpec`: its function, its parameter schema (names, types,
defaults, ranges, descriptions: :class:`MatcherParameter`), its presets, its default
largest disparity and its disparity resolution. The CLI's ``--matcher``/``--preset``
choices, ``disparity_node``'s parameters (names, ranges, descriptions) and the
validation of matcher parameters (:func:`compute_disparity`, the node) are all derived
from it. Two matchers are built in: ``sgbm`` (OpenCV, always) and ``elas``
(:mod:`canopy_stereo.elas`, numba). Their defaults are read from their implementations
(the keyword defaults of :func:`~canopy_stereo.disparity.sgbm.sgbm_disparity`, the fields
of :class:`~canopy_stereo.elas.params.ElasParams` and its ``PRESETS``), so they are stated
once; the schema adds what an implementation cannot say: descriptions and ranges.
Specs are built on first use, so listing the names imports no matcher.
"""
from __future__ import annotations

import importlib
import inspect
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.images import check_pair

#: Value written to pixels without a disparity.
INVALID_DISPARITY = -1.0

#: The paper's matcher: the default wherever it can be imported.
DEFAULT_MATCHER = "elas"

#: Arguments every matcher takes (the search range); not part of a matcher's parameters.
RANGE_ARGUMENTS = ("disp_min", "disp_max")


class Matcher(Protocol):
    """``matcher(left, right, disp_min=0, disp_max=..., **params) -> float32 (H, W)``."""

    def __call__(self, left: np.ndarray, right: np.ndarray, *, disp_min: int, disp_max: int,
                 **params) -> np.ndarray: ...


@dataclass(frozen=True)
class MatcherParameter:
    """One tunable parameter of a matcher.

    Attributes:
        name: keyword of the matcher function (``disparity_node``: ``<matcher>.<name>``).
        default: the matcher's default (None: computed by the matcher from other values).
        description: what it does, with its unit.
        kind: ``int``, ``float``, ``bool`` or ``str``.
        minimum, maximum: inclusive range of a number (None: unbounded).
        choices: allowed values of a string (empty: any).
    """

    name: str
    default: Any
    description: str
    kind: type
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple = ()

    @property
    def numeric(self) -> bool:
        """True for ``int`` and ``float`` parameters."""
        return self.kind in (int, float)

    def coerce(self, value, label: str | None = None):
        """``value`` as this parameter's type, within its range/choices; else
        :class:`CanopyStereoError` naming the parameter (``label``, default its name; an
        integral float is an int)."""
        name = label or self.name
        if self.kind is bool:
            if not isinstance(value, (bool, np.bool_)):
                raise CanopyStereoError(f"{name}: expected true/false, got {value!r}")
            return bool(value)
        if self.kind is str:
            if not isinstance(value, str):
                raise CanopyStereoError(f"{name}: expected a string, got {value!r}")
            if self.choices and value not in self.choices:
                raise CanopyStereoError(f"{name}: {value!r} is not one of {', '.join(self.choices)}")
            return value
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number)):
            raise CanopyStereoError(f"{name}: expected a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise CanopyStereoError(f"{name}: expected a finite number, got {value!r}")
        if self.kind is int:
            if float(value) != int(value):
                raise CanopyStereoError(f"{name}: expected an integer, got {value!r}")
            value = int(value)
        else:
            value = float(value)
        if (self.minimum is not None and value < self.minimum) or (
                self.maximum is not None and value > self.maximum):
            raise CanopyStereoError(f"{name}: {value!r} is out of range "
                                    f"[{self.minimum}, {self.maximum}]")
        return value


@dataclass(frozen=True)
class Declared:
    """What a schema states about a parameter beyond its default (see :func:`schema`)."""

    description: str
    minimum: float | None = None
    maximum: float | None = None
    kind: type | None = None
    choices: tuple = ()


def declare(description: str, *, minimum=None, maximum=None, kind: type | None = None,
            choices=()) -> Declared:
    """A parameter's description, inclusive range (numbers) or ``choices`` (strings);
    ``kind`` only where the default (None) cannot tell the type."""
    return Declared(description, minimum, maximum, kind, tuple(choices))


def schema(defaults: Mapping[str, Any], declared: Mapping[str, Declared],
           matcher: str) -> tuple[MatcherParameter, ...]:
    """The parameters of ``matcher``: names and defaults from the implementation
    (``defaults``), the rest from ``declared``; the two must name the same parameters."""
    missing, extra = sorted(set(defaults) - set(declared)), sorted(set(declared) - set(defaults))
    if missing or extra:
        raise CanopyStereoError(f"matcher {matcher!r}: schema and implementation disagree "
                                f"(undeclared: {missing}, not in the implementation: {extra})")
    out = []
    for name, default in defaults.items():
        d = declared[name]
        kind = d.kind or type(default)
        if kind not in (int, float, bool, str):
            raise CanopyStereoError(f"matcher {matcher!r}: parameter {name} has unsupported type {kind}")
        out.append(MatcherParameter(name, default, d.description, kind, d.minimum, d.maximum, d.choices))
    return tuple(out)


def keyword_defaults(function: Callable) -> dict:
    """``name -> default`` of ``function``'s keyword-only arguments other than the range."""
    sig = inspect.signature(function)
    return {n: p.default for n, p in sig.parameters.items()
            if p.kind == p.KEYWORD_ONLY and n not in RANGE_ARGUMENTS
            and p.default is not inspect.Parameter.empty}


@dataclass(frozen=True)
class MatcherSpec:
    """A registered matcher.

    Attributes:
        name: registry name (``elas``, ``sgbm``).
        function: the :class:`Matcher`.
        summary: one line about it.
        parameters: its tunable parameters (:class:`MatcherParameter`), range excluded.
        default_disp_max: largest disparity searched when nothing else says (pixels).
        resolution: disparity step of its output (pixels; ``delta_d`` of a DisparityImage).
        refined: ``(flag parameter, resolution)``: the resolution when that boolean
            parameter is true (ELAS ``subpixel``).
        presets: preset name -> parameter values (a ``preset`` keyword selects one).
        default_preset: the preset used when none is given.
        check_combination: ``f(params, disp_min, disp_max)`` raising
            :class:`CanopyStereoError` for values valid one by one but not together.
        compiled: its kernels are compiled on first use (numba): the CLI warms them up
            before timing (:func:`canopy_stereo.cli.progress.warm_up_kernels`).
    """

    name: str
    function: Callable
    summary: str = ""
    parameters: tuple[MatcherParameter, ...] = ()
    default_disp_max: int = 128
    resolution: float = 1.0
    refined: tuple[str, float] | None = None
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    default_preset: str | None = None
    check_combination: Callable | None = None
    compiled: bool = False

    def parameter(self, name: str) -> MatcherParameter:
        """The parameter ``name``; :class:`CanopyStereoError` listing the known ones."""
        for p in self.parameters:
            if p.name == name:
                return p
        raise CanopyStereoError(f"unknown {self.name} parameter {name!r}; known: "
                                f"{', '.join(p.name for p in self.parameters) or 'none'}")

    def defaults(self, preset: str | None = None) -> dict:
        """``name -> default`` of the parameters (with ``preset``'s values, or the default preset's)."""
        values = {p.name: p.default for p in self.parameters}
        preset = preset or self.default_preset
        if preset is not None:
            values.update(self.presets[self.check_preset(preset)])
        return values

    def check_preset(self, preset) -> str:
        """``preset`` if this matcher has it, else :class:`CanopyStereoError`."""
        if not self.presets:
            raise CanopyStereoError(f"matcher {self.name} has no presets")
        if preset not in self.presets:
            raise CanopyStereoError(f"unknown {self.name} preset {preset!r}; choose one of "
                                    f"{', '.join(self.presets)}")
        return str(preset)

    def check(self, params: Mapping[str, Any], disp_min: int | None = None,
              *, disp_max: int | None = None) -> dict:
        """``params`` with each value coerced and range-checked (``preset`` too, when the
        matcher has presets), then the combination checked for the search range;
        :class:`CanopyStereoError` naming the first problem."""
        out = {}
        for name, value in params.items():
            if name == "preset" and self.presets:
                out[name] = self.check_preset(value)
            else:
                out[name] = self.parameter(name).coerce(value)
        if self.check_combination is not None:
            lo = 0 if disp_min is None else int(disp_min)
            hi = self.default_disp_max if disp_max is None else int(disp_max)
            self.check_combination(out, lo, max(hi, lo + 1))
        return out

    def resolution_for(self, params: Mapping[str, Any]) -> float:
        """Disparity resolution (pixels) of the output with ``params``."""
        if self.refined is not None and params.get(self.refined[0]):
            return self.refined[1]
        return self.resolution


# ------------------------------------------------------------------ built-in matchers


def _sgbm_spec() -> MatcherSpec:
    from canopy_stereo.disparity.sgbm import SGBM_MODES, sgbm_disparity

    declared = {
        "block_size": declare("SGBM: side of the matched block (pixels, odd)", minimum=1, maximum=51),
        "p1": declare("SGBM: penalty of a disparity change of 1 pixel between neighbours "
                      "(unset: 8 * block_size^2)", minimum=0, maximum=10_000_000, kind=int),
        "p2": declare("SGBM: penalty of a larger disparity change between neighbours, > p1 "
                      "(unset: 32 * block_size^2)", minimum=0, maximum=10_000_000, kind=int),
        "uniqueness": declare("SGBM: margin (%) by which the best cost must beat the second best", minimum=0,
                              maximum=100),
        "speckle_window": declare("SGBM: largest speckle removed (pixels; 0 = no filtering)", minimum=0,
                                  maximum=100000),
        "speckle_range": declare("SGBM: largest disparity variation inside a connected speckle "
                                 "(pixels x 16)", minimum=0, maximum=1000),
        "disp12_max_diff": declare("SGBM: left-right consistency tolerance (pixels; -1 = off)", minimum=-1,
                                   maximum=4096),
        "mode": declare("SGBM: cost aggregation", choices=tuple(SGBM_MODES)),
    }
    defaults = keyword_defaults(sgbm_disparity)
    return MatcherSpec(
        name="sgbm", function=sgbm_disparity,
        summary="OpenCV semi-global block matching (Hirschmueller 2008)",
        parameters=schema(defaults, declared, "sgbm"),
        default_disp_max=int(inspect.signature(sgbm_disparity).parameters["disp_max"].default),
        resolution=1.0 / 16.0)  # OpenCV's fixed point: 4 fractional bits


def _elas_spec() -> MatcherSpec:
    from dataclasses import asdict, fields

    from canopy_stereo.elas.matcher import elas_matcher
    from canopy_stereo.elas.params import DEFAULT_PRESET, PRESETS, ElasParams, make_params

    declared = {
        "support_threshold": declare("ELAS: a support candidate is kept when its best matching cost is "
                                     "below this fraction of its second best (uniqueness ratio)",
                                     minimum=0.0, maximum=1.0),
        "support_texture": declare("ELAS: least descriptor texture of a support candidate", minimum=0,
                                   maximum=255),
        "candidate_stepsize": declare("ELAS: spacing of the support-candidate grid (pixels)", minimum=1,
                                      maximum=64),
        "incon_window_size": declare("ELAS: window (candidate cells) of the support consistency check",
                                     minimum=0, maximum=64),
        "incon_threshold": declare("ELAS: largest disparity difference (pixels) of consistent support "
                                   "points", minimum=0, maximum=255),
        "incon_min_support": declare("ELAS: consistent support points a support point needs in its "
                                     "window (itself included)", minimum=0, maximum=64),
        "add_corners": declare("ELAS: add the 4 image corners as support points and extrapolate to the "
                               "borders"),
        "grid_size": declare("ELAS: cell size of the disparity grid (pixels)", minimum=1, maximum=256),
        "beta": declare("ELAS: beta of the prior P[D] = (ln g - ln(g + exp(-D^2 / 2 s^2))) / beta",
                        minimum=0.0, maximum=100.0),
        "gamma": declare("ELAS: gamma (g) of the prior", minimum=0.0, maximum=100.0),
        "sigma": declare("ELAS: sigma (s) of the prior (pixels)", minimum=0.0, maximum=100.0),
        "sradius": declare("ELAS: plane search radius, in sigmas (max(ceil(sigma * sradius), 2) pixels)",
                           minimum=0.0, maximum=100.0),
        "match_texture": declare("ELAS: least descriptor texture of a densely matched pixel", minimum=0,
                                 maximum=255),
        "lr_threshold": declare("ELAS: left-right consistency tolerance (pixels)", minimum=0, maximum=64),
        "speckle_sim_threshold": declare("ELAS: largest disparity step (pixels) inside one speckle "
                                         "segment", minimum=0.0, maximum=255.0),
        "speckle_size": declare("ELAS: segments smaller than this (pixels) are removed", minimum=0,
                                maximum=100000),
        "ipol_gap_width": declare("ELAS: longest run of invalid pixels that gap interpolation fills "
                                  "(pixels)", minimum=0, maximum=10000),
        "filter_median": declare("ELAS: 7-tap separable median filter on the result"),
        "filter_adaptive_mean": declare("ELAS: 8-tap separable adaptive mean filter on the result"),
        "postprocess_only_left": declare("ELAS: skip speckle removal, interpolation and filters on the "
                                         "right map"),
        "subsampling": declare("ELAS: match every second row and column only (output repeated to full "
                               "size, disparities in full-resolution pixels)"),
        "subpixel": declare("ELAS: parabola sub-pixel refinement through the matching cost at d-1, d, d+1"),
        "adaptive_mean_weights": declare("ELAS: weights of the adaptive mean filter: step (the original "
                                         "as compiled) or linear (its stated intent)",
                                         choices=("step", "linear")),
    }
    base = ElasParams()
    defaults = {f.name: getattr(base, f.name) for f in fields(base) if f.name not in RANGE_ARGUMENTS}
    presets = {}
    for name, preset in PRESETS.items():
        values = asdict(preset)
        presets[name] = {k: v for k, v in values.items() if k not in RANGE_ARGUMENTS and v != defaults[k]}

    def check_combination(params, disp_min, disp_max):
        values = {k: v for k, v in params.items() if k != "preset"}
        make_params(params.get("preset", DEFAULT_PRESET), disp_min=disp_min, disp_max=disp_max, **values)

    return MatcherSpec(
        name="elas", function=elas_matcher,
        summary="ELAS (Geiger et al., ACCV 2010), the paper's matcher, in numba",
        parameters=schema(defaults, declared, "elas"),
        default_disp_max=int(base.disp_max), resolution=1.0, refined=("subpixel", 1.0 / 16.0),
        presets=presets, default_preset=DEFAULT_PRESET,
        check_combination=check_combination, compiled=True)


# name -> its spec, or the factory that builds it on first use
_MATCHERS: dict[str, MatcherSpec | Callable[[], MatcherSpec]] = {
    "sgbm": _sgbm_spec,
    "elas": _elas_spec,
}


def register_matcher(name: str, matcher: str | Callable | MatcherSpec, *, summary: str = "",
                     declared: Mapping[str, Declared] | None = None, default_disp_max: int = 128,
                     resolution: float = 1.0) -> None:
    """Register ``matcher`` (a callable, ``"module:function"`` or a full :class:`MatcherSpec`)
    under ``name``. For a function, its parameters are its keyword-only arguments with
    defaults; ``declared`` (:func:`declare`) gives their descriptions and ranges (without
    it, a generic description and no range)."""
    if isinstance(matcher, MatcherSpec):
        _MATCHERS[name] = matcher
        return

    def factory() -> MatcherSpec:
        fn = _import(name, matcher) if isinstance(matcher, str) else matcher
        defaults = keyword_defaults(fn)
        decl = dict(declared) if declared is not None else {
            n: declare(f"{name}: parameter {n} of the matcher") for n in defaults}
        for n, v in defaults.items():  # untyped defaults (None) cannot be declared generically
            if v is None and n in decl and decl[n].kind is None:
                raise CanopyStereoError(f"matcher {name!r}: declare the type of parameter {n} (default None)")
        return MatcherSpec(name=name, function=fn, summary=summary, parameters=schema(defaults, decl, name),
                           default_disp_max=default_disp_max, resolution=resolution)

    _MATCHERS[name] = factory


def _import(name: str, target: str) -> Callable:
    module, func = target.split(":")
    try:
        return getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        raise CanopyStereoError(f"matcher {name!r} is not available: {exc}") from None


def matcher_names() -> list[str]:
    """Names of all registered matchers, sorted (whether importable here or not)."""
    return sorted(_MATCHERS)


def unknown_matcher(name) -> CanopyStereoError:
    """The one error for a matcher name that is not registered (lists the registered ones)."""
    return CanopyStereoError(f"unknown matcher {name!r}; choose one of {', '.join(matcher_names())}")


def matcher_spec(name: str) -> MatcherSpec:
    """The :class:`MatcherSpec` registered as ``name`` (built on first use); raises
    :class:`CanopyStereoError` if unknown (listing the registered ones) or not importable."""
    target = _MATCHERS.get(name) if isinstance(name, str) else None
    if target is None:
        raise unknown_matcher(name)
    if isinstance(target, MatcherSpec):
        return target
    try:
        spec = target()
    except ImportError as exc:
        raise CanopyStereoError(f"matcher {name!r} is not available: {exc}") from None
    _MATCHERS[name] = spec
    return spec


def available_matchers() -> list[str]:
    """Names of the registered matchers whose implementation can be imported."""
    names = []
    for name in list(_MATCHERS):
        try:
            matcher_spec(name)
        except CanopyStereoError:
            continue
        names.append(name)
    return names


def default_matcher() -> str:
    """:data:`DEFAULT_MATCHER` when it can be imported here, else the first available one."""
    available = available_matchers()
    if DEFAULT_MATCHER in available or not available:
        return DEFAULT_MATCHER
    return sorted(available)[0]


def preset_names() -> list[str]:
    """Presets of the available matchers (``--preset``, ``disparity_node``'s ``preset``)."""
    names = []
    for name in available_matchers():
        names += [p for p in matcher_spec(name).presets if p not in names]
    return names


def get_matcher(name: str) -> Matcher:
    """The matcher function registered as ``name``; raises :class:`CanopyStereoError` if unknown."""
    return matcher_spec(name).function


def compute_disparity(left: np.ndarray, right: np.ndarray, *, matcher: str = DEFAULT_MATCHER,
                      disp_min: int = 0, disp_max: int = 128, **params) -> np.ndarray:
    """Left disparity (float32 (H, W), pixels, invalid = -1) of a rectified pair.

    Args:
        left, right: rectified uint8 images (grey or BGR) of equal size.
        matcher: registered matcher name (default :data:`DEFAULT_MATCHER`, ``"elas"``, as
            every entry point; ``"sgbm"``, ...).
        disp_min, disp_max: search range in pixels (``disp_max > disp_min``).
        **params: matcher-specific parameters, checked against the matcher's schema
            (:meth:`MatcherSpec.check`: names, types, ranges).
    """
    spec = matcher_spec(matcher)
    left, right = np.asarray(left), np.asarray(right)
    check_pair(left, right)
    if left.dtype != np.uint8 or right.dtype != np.uint8:
        raise ImageError(f"matcher input must be uint8 images, got {left.dtype}/{right.dtype}")
    if disp_max <= disp_min:
        raise CanopyStereoError(f"disp_max ({disp_max}) must be greater than disp_min ({disp_min})")
    params = spec.check(params, disp_min, disp_max=disp_max)
    disp = spec.function(left, right, disp_min=int(disp_min), disp_max=int(disp_max), **params)
    disp = np.asarray(disp, dtype=np.float32)
    disp[~np.isfinite(disp)] = INVALID_DISPARITY
    return disp
