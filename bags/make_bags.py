"""Regenerate the bundled bags and their rig files.

    .venv/bin/python bags/make_bags.py [--data ../shared/data] [--frames 4]

Writes bags/croton.mcap + config/croton_rig.yaml (synthetic croton through the
paper's rig, rendered by canopy_stereo.sim) and bags/plants.mcap +
config/plants_rig.yaml (Middlebury 2014 "Plants", quarter size, from
<data>/middlebury_MiddEval3_testQ/Plants). See canopy_stereo/ros/bundled.py.
"""
import argparse
from pathlib import Path

from canopy_stereo.bag import BagReader
from canopy_stereo.io.rig import load_rig
from canopy_stereo.ros.bundled import make_croton, make_plants

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data")
    p.add_argument("--frames", type=int, default=4, help="croton frames")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args()
    paper = load_rig(REPO / "config" / "paper_rig.yaml")
    outputs = [make_croton(REPO / "bags" / "croton.mcap", REPO / "config" / "croton_rig.yaml",
                           paper, n_frames=a.frames, seed=a.seed),
               make_plants(REPO / "bags" / "plants.mcap", REPO / "config" / "plants_rig.yaml",
                           a.data / "middlebury_MiddEval3_testQ" / "Plants")]
    for bag, rig in outputs:
        print(BagReader(bag).summary_text())
        print(f"size: {bag.stat().st_size / 1e6:.2f} MB; rig: {rig}")


if __name__ == "__main__":
    main()
