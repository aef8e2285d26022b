"""Name -> matcher registry (``sgbm`` always; ``elas`` from :mod:`canopy_stereo.elas`)."""
from __future__ import annotations

import importlib
from typing import Callable, Protocol

import numpy as np

from canopy_stereo.errors import CanopyStereoError, ImageError
from canopy_stereo.io.images import check_pair

#: Value written to pixels without a disparity.
INVALID_DISPARITY = -1.0


class Matcher(Protocol):
    """``matcher(left, right, disp_min=0, disp_max=..., **params) -> float32 (H, W)``."""

    def __call__(self, left: np.ndarray, right: np.ndarray, *, disp_min: int, disp_max: int,
                 **params) -> np.ndarray: ...


# name -> "module:function" (imported on first use) or a callable
_MATCHERS: dict[str, str | Callable] = {
    "sgbm": "canopy_stereo.disparity.sgbm:sgbm_disparity",
    "elas": "canopy_stereo.elas.matcher:elas_matcher",
}


def register_matcher(name: str, matcher: str | Callable) -> None:
    """Register ``matcher`` (a callable or ``"module:function"``) under ``name``."""
    _MATCHERS[name] = matcher


def matcher_names() -> list[str]:
    """Names of all registered matchers, sorted (whether importable here or not)."""
    return sorted(_MATCHERS)


def available_matchers() -> list[str]:
    """Names of the registered matchers whose implementation can be imported."""
    names = []
    for name in _MATCHERS:
        try:
            get_matcher(name)
        except CanopyStereoError:
            continue
        names.append(name)
    return names


def get_matcher(name: str) -> Matcher:
    """The matcher registered as ``name``; raises :class:`CanopyStereoError` if unknown."""
    target = _MATCHERS.get(name)
    if target is None:
        raise CanopyStereoError(
            f"unknown matcher {name!r}; choose one of {', '.join(sorted(_MATCHERS))}")
    if callable(target):
        return target
    module, func = target.split(":")
    try:
        fn = getattr(importlib.import_module(module), func)
    except (ImportError, AttributeError) as exc:
        raise CanopyStereoError(f"matcher {name!r} is not available: {exc}") from None
    _MATCHERS[name] = fn
    return fn


def compute_disparity(left: np.ndarray, right: np.ndarray, *, matcher: str = "sgbm",
                      disp_min: int = 0, disp_max: int = 128, **params) -> np.ndarray:
    """Left disparity (float32 (H, W), pixels, invalid = -1) of a rectified pair.

    Args:
        left, right: rectified uint8 images (grey or BGR) of equal size.
        matcher: registered matcher name (``"sgbm"``, ``"elas"``).
        disp_min, disp_max: search range in pixels (``disp_max > disp_min``).
        **params: matcher-specific parameters.
    """
    left, right = np.asarray(left), np.asarray(right)
    check_pair(left, right)
    if left.dtype != np.uint8 or right.dtype != np.uint8:
        raise ImageError(f"matcher input must be uint8 images, got {left.dtype}/{right.dtype}")
    if disp_max <= disp_min:
        raise CanopyStereoError(f"disp_max ({disp_max}) must be greater than disp_min ({disp_min})")
    disp = get_matcher(matcher)(left, right, disp_min=int(disp_min), disp_max=int(disp_max), **params)
    disp = np.asarray(disp, dtype=np.float32)
    disp[~np.isfinite(disp)] = INVALID_DISPARITY
    return disp
