"""Unknown rig-file keys are an error naming the nearest valid key (issue 23, item 5)."""
from __future__ import annotations

from pathlib import Path

import pytest

from canopy_stereo.errors import RigError
from canopy_stereo.io.rig import load_rig, rig_from_yaml
from canopy_stereo.io.rig_keys import VALID_KEYS

REPO = Path(__file__).resolve().parents[2]


def _with_line(line: str) -> str:
    text = (REPO / "config/croton_rig.yaml").read_text()
    return text.rstrip("\n") + "\n    " + line + "\n"


@pytest.mark.parametrize(("line", "nearest"), [("disp_mx: 90", "disp_max"), ("P_lefft: [1]", "P_left"),
                                               ("Near_m: 0.3", "near_m"), ("world_units: m", "world_unit")])
def test_a_typo_is_refused_naming_the_nearest_key(line, nearest):
    with pytest.raises(RigError) as exc:
        rig_from_yaml(_with_line(line), source="rig.yaml")
    msg = str(exc.value)
    assert "\n" not in msg and f"unknown key '{line.split(':')[0]}'" in msg and f"'{nearest}'" in msg


def test_valid_extras_and_matcher_parameters_are_kept():
    rig = rig_from_yaml(_with_line("elas.match_texture: 1"), source="rig.yaml")
    assert rig.extra["elas"] == {"subpixel": True} and rig.extra["elas.match_texture"] == 1
    rig = rig_from_yaml(_with_line("near_m: 0.3"), source="rig.yaml")
    assert rig.extra["near_m"] == 0.3
    with pytest.raises(RigError, match="see canopy_stereo.io.rig_keys"):
        rig_from_yaml(_with_line("zzzqqq: 1"), source="rig.yaml")


def test_the_cli_refuses_a_typo_with_exit_2(cli, tmp_path):
    bad = tmp_path / "rig.yaml"
    bad.write_text(_with_line("disp_mx: 90"))
    code, out, err = cli("rectify", "x.png", "y.png", "--rig", bad, "-o", tmp_path / "r")
    assert code == 2 and "did you mean 'disp_max'" in err and "Traceback" not in err


@pytest.mark.ros
def test_every_parameter_a_node_declares_is_a_valid_rig_key():
    """A rig file is every node's --params-file: each node parameter may sit in it."""
    pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter

    from canopy_stereo.ros.context import ros_context
    from canopy_stereo.ros.fusion_node import FusionNode
    from canopy_stereo.ros.graph import CanopyGraph, GraphOptions

    rig = load_rig(REPO / "config/croton_rig.yaml")
    declared: dict[str, set] = {}
    with ros_context() as ctx:
        graph = CanopyGraph(rig, ctx, GraphOptions(segment=True, parameter_services=False))
        try:
            for name, node in graph.nodes.items():
                declared[name] = set(node._parameters)
        finally:
            graph.shutdown()
        node = FusionNode(context=ctx, start_parameter_services=False,
                          parameter_overrides=[Parameter("rig_file", value=str(REPO / "config/croton_rig.yaml"))])
        try:
            declared["fusion_node"] = set(node._parameters)
        finally:
            node.destroy_node()
    for name, params in declared.items():
        unknown = {p for p in params if p not in VALID_KEYS and p.split(".")[0] not in VALID_KEYS}
        assert not unknown, f"{name} declares parameters canopy_stereo.io.rig_keys does not list: {sorted(unknown)}"
