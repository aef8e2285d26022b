"""One call from a scene name to a rendered, ground-truthed stereo pair."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError, RigError
from canopy_stereo.io.rig import Rig, load_rig
from canopy_stereo.sim.render import SimResult, render_pair
from canopy_stereo.sim.scene import Scene, place_in_front_of
from canopy_stereo.sim.scenes import build_scene
from canopy_stereo.sim.sensor import CameraEffects

PAPER_RIG_NAME = "paper_rig.yaml"


def default_rig_path() -> Path:
    """Path of ``config/paper_rig.yaml``: in the source tree, else in the
    ``share/canopy_stereo/config`` folder of the environment (pip or colcon
    install), else the ROS 2 share folder; raises :class:`RigError` if none exists."""
    import sys

    for base in (Path(__file__).resolve().parents[2] / "config",
                 Path(sys.prefix) / "share" / "canopy_stereo" / "config"):
        if (base / PAPER_RIG_NAME).is_file():
            return base / PAPER_RIG_NAME
    try:
        from ament_index_python.packages import get_package_share_directory

        shared = Path(get_package_share_directory("canopy_stereo")) / "config" / PAPER_RIG_NAME
        if shared.is_file():
            return shared
    except (ImportError, LookupError, ValueError):
        pass
    raise RigError(f"cannot find the default rig {PAPER_RIG_NAME} (source tree or ROS share); "
                   "pass a rig file explicitly")


def resolve_rig(rig) -> Rig:
    """A :class:`Rig` from a Rig, a rig-file path, or None (the paper's rig)."""
    if rig is None:
        return load_rig(default_rig_path())
    if isinstance(rig, Rig):
        return rig
    return load_rig(rig)


def rig_at_resolution(rig: Rig, scale: float) -> Rig:
    """The same two cameras imaging at ``scale`` times the resolution (e.g. 0.25
    for quick 160x120 renders of a 640x480 rig).

    Pixel areas map exactly: with pixel centres at integers, ``u' = s (u + 1/2) - 1/2``,
    so ``P' = T P`` with ``T = [[s, 0, (s-1)/2], [0, s, (s-1)/2], [0, 0, 1]]``. The
    image size must scale to whole pixels. Distortion coefficients are unchanged
    (they act on normalised coordinates).
    """
    w, h = rig.image_size
    nw, nh = w * scale, h * scale
    if scale <= 0 or abs(nw - round(nw)) > 1e-9 or abs(nh - round(nh)) > 1e-9:
        raise CanopyStereoError(f"scale {scale} does not turn {w}x{h} into whole pixels")
    T = np.array([[scale, 0, (scale - 1) / 2], [0, scale, (scale - 1) / 2], [0, 0, 1.0]])
    return replace(rig, P_left=T @ rig.P_left, P_right=T @ rig.P_right,
                   image_size=(int(round(nw)), int(round(nh))))


def scene_for_rig(name: str, rig=None, *, seed: int = 0, frame: int = 0) -> Scene:
    """The named scene at ``frame``, placed in front of ``rig`` (world frame and unit)."""
    return place_in_front_of(build_scene(name, seed).at_frame(frame), resolve_rig(rig))


def render_scene(name: str, rig=None, *, seed: int = 0, frame: int = 0, effects: CameraEffects | None = None,
                 supersample: int = 2) -> SimResult:
    """Render the named scene through ``rig`` (a Rig, a rig path, or None for
    ``config/paper_rig.yaml``). Deterministic for given arguments."""
    rig = resolve_rig(rig)
    scene = place_in_front_of(build_scene(name, seed).at_frame(frame), rig)
    return render_pair(scene, rig, supersample=supersample, effects=effects)
