"""Matcher knowledge lives in the registry: its schema agrees with the implementations, and
the CLI choices, disparity_node's parameters (read through the descriptors of a live node)
and the launch file are derived from it; an unknown matcher fails with one line listing
the registered ones."""
import argparse
import inspect
from dataclasses import asdict

import numpy as np
import pytest

from canopy_stereo.disparity import (
    DEFAULT_MATCHER,
    available_matchers,
    compute_disparity,
    declare,
    matcher_names,
    matcher_spec,
    preset_names,
    register_matcher,
    registry,
)
from canopy_stereo.errors import CanopyStereoError

UNKNOWN = "unknown matcher 'foo'; choose one of elas, sgbm"


def test_registry_defaults_are_the_implementations():
    from canopy_stereo.disparity.sgbm import sgbm_disparity
    from canopy_stereo.elas.params import PRESETS, ElasParams

    assert matcher_names() == ["elas", "sgbm"] and sorted(available_matchers()) == ["elas", "sgbm"]
    elas, sgbm = matcher_spec("elas"), matcher_spec("sgbm")
    base = {k: v for k, v in asdict(ElasParams()).items() if k not in ("disp_min", "disp_max")}
    assert elas.defaults() == base
    for name, preset in PRESETS.items():
        want = {k: v for k, v in asdict(preset).items() if k not in ("disp_min", "disp_max")}
        assert elas.defaults(name) == want
    assert elas.default_disp_max == ElasParams().disp_max == 255 and elas.default_preset == "robotics"
    sig = inspect.signature(sgbm_disparity).parameters
    assert sgbm.defaults() == {n: p.default for n, p in sig.items()
                               if p.kind == p.KEYWORD_ONLY and n not in ("disp_min", "disp_max")}
    assert sgbm.default_disp_max == sig["disp_max"].default == 128
    assert preset_names() == list(PRESETS)
    for spec in (elas, sgbm):
        for p in spec.parameters:
            assert p.kind in (int, float, bool, str) and len(p.description) > 20, p
            if p.numeric:
                assert p.minimum is not None and p.maximum is not None and p.minimum < p.maximum, p
            if p.default is not None:  # every default passes its own schema
                assert p.coerce(p.default) == p.default
        for preset in spec.presets:
            spec.check(spec.defaults(preset))
    # the disparity resolution (DisparityImage.delta_d)
    assert sgbm.resolution_for({}) == 1 / 16
    assert elas.resolution_for({}) == 1.0 and elas.resolution_for({"subpixel": True}) == 1 / 16


def test_compute_disparity_validates_against_the_schema():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 255, (40, 60), np.uint8)
    with pytest.raises(CanopyStereoError) as err:
        compute_disparity(img, img, matcher="foo")
    assert str(err.value) == UNKNOWN
    with pytest.raises(CanopyStereoError, match="unknown sgbm parameter 'window'; known: block_size, p1"):
        compute_disparity(img, img, matcher="sgbm", window=3)
    with pytest.raises(CanopyStereoError, match=r"block_size: 99 is out of range \[1, 51\]"):
        compute_disparity(img, img, matcher="sgbm", block_size=99)
    with pytest.raises(CanopyStereoError, match="mode: 'fast' is not one of sgbm, hh, 3way"):
        compute_disparity(img, img, matcher="sgbm", mode="fast")
    with pytest.raises(CanopyStereoError, match="unknown elas preset 'kitti'; choose one of robotics, middlebury"):
        compute_disparity(img, img, matcher="elas", preset="kitti")
    with pytest.raises(CanopyStereoError, match="subpixel: expected true/false"):
        compute_disparity(img, img, matcher="elas", subpixel=1)


def test_compute_disparity_defaults_to_the_package_matcher_elas():
    from canopy_stereo.disparity import DEFAULT_MATCHER

    assert DEFAULT_MATCHER == "elas"
    rng = np.random.default_rng(1)
    left = rng.integers(0, 255, (48, 64), np.uint8)
    right = np.roll(left, -5, axis=1)  # the scene 5 px to the left in the right image
    default = compute_disparity(left, right, disp_min=0, disp_max=16)
    np.testing.assert_array_equal(default, compute_disparity(left, right, matcher="elas", disp_min=0, disp_max=16))
    assert not np.array_equal(default, compute_disparity(left, right, matcher="sgbm", disp_min=0, disp_max=16))


def _subparsers(parser):
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _option(parser, flag):
    return next(a for a in parser._actions if flag in a.option_strings)


def test_cli_choices_come_from_the_registry():
    from canopy_stereo.cli import build_parser

    commands = _subparsers(build_parser())
    for command in ("disparity", "reconstruct", "run", "demo", "view", "batch", "fuse"):
        assert list(_option(commands[command], "--matcher").choices) == matcher_names(), command
    assert _option(commands["reconstruct"], "--matcher").default == DEFAULT_MATCHER
    assert list(_option(commands["disparity"], "--preset").choices) == preset_names()
    help_text = _option(commands["disparity"], "--disp-max").help
    for name in available_matchers():
        assert f"{matcher_spec(name).default_disp_max} for {name}" in help_text


def test_cli_unknown_matcher_lists_the_registered_ones(cli, tmp_path):
    code, _, err = cli("disparity", tmp_path / "l.png", tmp_path / "r.png", "-o", tmp_path / "d.pfm",
                       "--matcher", "foo")
    assert code == 2
    assert "invalid choice: 'foo' (choose from 'elas', 'sgbm')" in err.strip().splitlines()[-1]


def test_register_matcher_derives_its_schema(monkeypatch):
    def box(left, right, *, disp_min=0, disp_max=16, radius: int = 2, smooth: bool = False):
        return np.zeros(np.asarray(left).shape[:2], np.float32)

    monkeypatch.setitem(registry._MATCHERS, "box", None)  # removed again after the test
    register_matcher("box", box, declared={"radius": declare("box: half side (pixels)", minimum=0, maximum=10),
                                           "smooth": declare("box: smooth the result")})
    assert "box" in matcher_names() and "box" in available_matchers()
    spec = matcher_spec("box")
    assert spec.defaults() == {"radius": 2, "smooth": False} and spec.parameter("radius").maximum == 10
    img = np.zeros((8, 8), np.uint8)
    assert compute_disparity(img, img, matcher="box", radius=3).shape == (8, 8)
    with pytest.raises(CanopyStereoError, match=r"radius: 11 is out of range"):
        compute_disparity(img, img, matcher="box", radius=11)
    with pytest.raises(CanopyStereoError, match="schema and implementation disagree"):
        register_matcher("box", box, declared={"radius": declare("box: half side (pixels)", minimum=0,
                                                                 maximum=10)})
        matcher_spec("box")


@pytest.mark.ros
def test_disparity_node_parameters_are_the_registry(tmp_path):
    pytest.importorskip("rclpy")
    pytest.importorskip("stereo_msgs.msg")
    from rclpy.parameter import Parameter

    from canopy_stereo.ros.context import ros_context
    from canopy_stereo.ros.nodes.disparity import DisparityNode

    with ros_context() as ctx:
        node = DisparityNode(context=ctx, start_parameter_services=False)
        try:
            declared = {n for n in node._parameters if "." in n and not n.startswith("qos_overrides.")}
            want = {f"{m}.{p.name}" for m in available_matchers() for p in matcher_spec(m).parameters}
            assert declared == want
            for m in available_matchers():
                spec = matcher_spec(m)
                names = [f"{m}.{p.name}" for p in spec.parameters]
                for p, d in zip(spec.parameters, node.describe_parameters(names)):
                    assert d.description.startswith(p.description), (p.name, d.description)
                    if p.kind is int:
                        r = d.integer_range[0]
                        assert (r.from_value, r.to_value) == (p.minimum, p.maximum), p.name
                    elif p.kind is float:
                        r = d.floating_point_range[0]
                        assert (r.from_value, r.to_value) == (p.minimum, p.maximum), p.name
                    else:
                        assert not d.integer_range and not d.floating_point_range
                    for choice in p.choices:
                        assert choice in d.description
            matcher = node.describe_parameter("matcher")
            assert f"({' | '.join(matcher_names())})" in matcher.description
            assert f"({' | '.join(preset_names())})" in node.describe_parameter("preset").description
            assert node.get_parameter("matcher").value == DEFAULT_MATCHER
            # the published resolution is the registry's
            assert node.config["delta_d"] == matcher_spec(DEFAULT_MATCHER).resolution_for(node.config["params"])
            refused = node.set_parameters([Parameter("matcher", value="foo")])[0]
            assert not refused.successful and refused.reason == UNKNOWN
            refused = node.set_parameters([Parameter("sgbm.mode", value="fast")])[0]
            assert not refused.successful and "sgbm.mode: 'fast' is not one of sgbm, hh, 3way" in refused.reason
        finally:
            node.destroy_node()
        with pytest.raises(CanopyStereoError) as err:
            DisparityNode(context=ctx, start_parameter_services=False,
                          parameter_overrides=[Parameter("matcher", value="foo")])
        assert str(err.value) == UNKNOWN


@pytest.mark.ros
def test_graph_and_launch_matcher_choices_come_from_the_registry():
    pytest.importorskip("rclpy")
    pytest.importorskip("stereo_msgs.msg")
    from canopy_stereo.ros.canopy_graph import build_parser
    from test.support.launch_eval import evaluate

    assert list(_option(build_parser(), "--matcher").choices) == matcher_names()
    _, declared = evaluate({})
    assert list(declared["matcher"].choices) == matcher_names()
    assert declared["matcher"].default_value == DEFAULT_MATCHER
