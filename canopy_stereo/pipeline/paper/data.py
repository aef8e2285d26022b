"""The shipped stereo pairs the paper run measures: the real Plants pair and rendered scenes."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from canopy_stereo.errors import CanopyStereoError


@dataclass
class StereoPair:
    """A shipped stereo pair: images, rig and (rendered scenes) the exact truth."""

    key: str
    title: str
    left: np.ndarray
    right: np.ndarray
    rig: object
    sim: object = None                   # SimResult for rendered scenes


def plants_pair() -> StereoPair:
    """The bundled Middlebury "Plants" pair and its rig (from ``bags/plants.mcap``;
    the source tree's ``examples/plants`` PNGs when the ROS message packages are absent)."""
    from canopy_stereo.io.rig import load_rig
    from canopy_stereo.ros.bundled import bundled_rig

    rig = load_rig(bundled_rig("plants"))
    folder = Path(__file__).resolve().parents[2] / "examples" / "plants"
    try:
        from canopy_stereo.bag import BagReader
        from canopy_stereo.ros.bundled import LEFT_TOPIC, RIGHT_TOPIC, bundled_bag
        from canopy_stereo.ros.convert import msg_to_image

        bag = BagReader(bundled_bag("plants"))
        left = next(iter(bag.read(LEFT_TOPIC)))[1]
        right = next(iter(bag.read(RIGHT_TOPIC)))[1]
        left, right = msg_to_image(left, ("bgr8",)), msg_to_image(right, ("bgr8",))
    except ImportError:
        from canopy_stereo.io.images import read_image

        if not (folder / "left.png").is_file():
            raise CanopyStereoError("the Plants pair needs the ROS message packages (pip install "
                                    "-e '.[ros]') or the source tree's examples/plants") from None
        left, right = read_image(folder / "left.png"), read_image(folder / "right.png")
    return StereoPair("plants", "Middlebury 2014 Plants (real)", np.ascontiguousarray(left),
                      np.ascontiguousarray(right), rig)


def rendered_pair(scene: str, seed: int = 0) -> StereoPair:
    """A scene of :mod:`canopy_stereo.sim` through the paper's rig."""
    from canopy_stereo.sim import render_scene

    sim = render_scene(scene, seed=seed)
    return StereoPair(scene, f"synthetic {scene.replace('_', ' ')} (seed {seed})", sim.left,
                      sim.right, sim.rig, sim)
