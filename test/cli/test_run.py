"""``canopy-stereo run``: the bundled croton bag through the node graph, its figures and recording."""
import re

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stereo_msgs.msg")

from canopy_stereo.bag import BagReader  # noqa: E402
from canopy_stereo.ros.bundled import bundled_bag, bundled_rig  # noqa: E402

pytestmark = pytest.mark.ros


def test_cli_run_prints_figures_and_records(tmp_path, cli):
    bag = bundled_bag("croton")
    out = tmp_path / "run.mcap"
    code, stdout, stderr = cli("run", "--bag", bag, "--rig", bundled_rig("croton"), "--rate", "0",
                               "--record", out, "--matcher", "sgbm", "--no-segment")
    assert code == 0, stderr
    assert "frames in: 4, frames out: 4" in stdout
    assert re.search(r"throughput: [0-9.]+ frames/s", stdout)
    assert re.search(r"latency raw pair -> points2: median \d+ ms", stdout)
    rec = BagReader(out)
    assert rec.topics["/stereo/points2"].message_count == 4 and "/stereo/left/mask" not in rec.topics
    code, _, stderr = cli("run", "--bag", tmp_path / "missing.mcap", "--rig", bundled_rig("croton"))
    assert code == 2 and "bag not found" in stderr and "Traceback" not in stderr
