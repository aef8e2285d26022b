"""Evaluate ``launch/canopy_stereo.launch.py`` without ROS 2's ``launch`` packages.

``launch`` and ``launch_ros`` are not on PyPI, so the tests cannot ``ros2 launch``. This
module evaluates the launch file the way ``ros2 launch`` does, for the part of the launch
API the file uses, and the tests then start the resulting command lines as processes
(:class:`ros_harness.ProcessGroup`):

* ``generate_launch_description()`` runs for real, against small implementations of
  ``LaunchDescription``, ``DeclareLaunchArgument``, ``IfCondition``/``UnlessCondition``,
  ``LaunchConfiguration``, ``PathJoinSubstitution``, ``PythonExpression``,
  ``launch_ros.actions.Node`` and ``FindPackageShare``, installed as the ``launch`` and
  ``launch_ros`` modules only while the file is loaded (anything else the file imported
  would fail the import, so the tests notice when the file leaves this subset);
* semantics follow launch/launch_ros (Jazzy): launch arguments given on the command line
  override ``default_value``; substitutions are performed into strings and
  concatenated; ``PythonExpression`` is ``eval`` of the concatenation (with ``math``);
  conditions accept ``true``/``false``/``1``/``0`` (any case); a ``Node`` becomes
  ``<executable> <arguments> --ros-args -r __node:=<name> -r __ns:=<namespace>
  --params-file <file>...``, where each parameter *dict* is written to a temporary
  parameter file under ``/**`` with every performed string value read as YAML (as
  launch_ros does: ``"15.0"`` becomes a double, ``"false"`` a bool, ``"[1, 2]"`` a list;
  an empty string is YAML null, which launch_ros rejects, and so does this), and each
  path is passed as ``--params-file`` itself;
* ``FindPackageShare("canopy_stereo")`` is the package's share directory when the ament
  index knows it, else the checkout (it has the same ``config/``, ``launch/``, ``bags/``).
"""
from __future__ import annotations

import importlib.util
import math
import os
import sys
import tempfile
import types
from dataclasses import dataclass, field
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / "launch" / "canopy_stereo.launch.py"


class LaunchContext:
    """Launch configurations (name -> string)."""

    def __init__(self, arguments: dict):
        self.launch_configurations = {k: str(v) for k, v in arguments.items()}


def perform(value, context: LaunchContext) -> str:
    """A substitution, string, number or list of them -> the concatenated string."""
    if isinstance(value, (list, tuple)):
        return "".join(perform(v, context) for v in value)
    if hasattr(value, "perform"):
        return value.perform(context)
    return str(value)


class Substitution:
    def perform(self, context: LaunchContext) -> str:  # pragma: no cover - interface
        raise NotImplementedError


class LaunchConfiguration(Substitution):
    def __init__(self, variable_name, default=None):
        self.name, self.default = variable_name, default

    def perform(self, context):
        if self.name in context.launch_configurations:
            return context.launch_configurations[self.name]
        if self.default is not None:
            return perform(self.default, context)
        raise KeyError(f"launch configuration {self.name!r} is not set")


class PythonExpression(Substitution):
    def __init__(self, expression):
        self.expression = expression

    def perform(self, context):
        return str(eval(perform(self.expression, context), {"math": math}, {}))


class PathJoinSubstitution(Substitution):
    def __init__(self, substitutions):
        self.parts = substitutions

    def perform(self, context):
        return os.path.join(*[perform(p, context) for p in self.parts])


class FindPackageShare(Substitution):
    def __init__(self, package):
        self.package = package

    def perform(self, context):
        try:
            from ament_index_python.packages import get_package_share_directory

            return get_package_share_directory(perform(self.package, context))
        except Exception:  # noqa: BLE001 - not installed in an ament prefix: the checkout
            return str(REPO)


def _truth(text: str) -> bool:
    t = text.strip().lower()
    if t in ("true", "1"):
        return True
    if t in ("false", "0"):
        return False
    raise ValueError(f"condition expression must be true/false/1/0, got {text!r}")


class IfCondition:
    def __init__(self, predicate_expression):
        self.expression = predicate_expression

    def evaluate(self, context):
        return _truth(perform(self.expression, context))


class UnlessCondition(IfCondition):
    def evaluate(self, context):
        return not super().evaluate(context)


class DeclareLaunchArgument:
    def __init__(self, name, *, default_value=None, description="", choices=None, **_):
        self.name, self.default_value, self.description, self.choices = name, default_value, description, choices


class LaunchDescription:
    def __init__(self, initial_entities=None):
        self.entities = list(initial_entities or [])


class Node:
    def __init__(self, *, executable, package=None, name=None, namespace=None, parameters=None,
                 arguments=None, remappings=None, condition=None, output=None, **_):
        self.package, self.executable, self.name, self.namespace = package, executable, name, namespace
        self.parameters = list(parameters or [])
        self.arguments = list(arguments or [])
        self.remappings = list(remappings or [])
        self.condition = condition


@dataclass
class NodeCommand:
    """A ``Node`` action evaluated: what ``ros2 launch`` would execute."""

    package: str
    executable: str
    name: str | None
    arguments: list = field(default_factory=list)
    ros_args: list = field(default_factory=list)
    parameters: dict = field(default_factory=dict)  # merged values of the parameter dicts (for tests)
    params_files: list = field(default_factory=list)


def _modules() -> dict:
    launch = types.ModuleType("launch")
    launch.LaunchDescription = LaunchDescription
    actions = types.ModuleType("launch.actions")
    actions.DeclareLaunchArgument = DeclareLaunchArgument
    conditions = types.ModuleType("launch.conditions")
    conditions.IfCondition, conditions.UnlessCondition = IfCondition, UnlessCondition
    subs = types.ModuleType("launch.substitutions")
    subs.LaunchConfiguration, subs.PathJoinSubstitution = LaunchConfiguration, PathJoinSubstitution
    subs.PythonExpression = PythonExpression
    launch_ros = types.ModuleType("launch_ros")
    ros_actions = types.ModuleType("launch_ros.actions")
    ros_actions.Node = Node
    ros_subs = types.ModuleType("launch_ros.substitutions")
    ros_subs.FindPackageShare = FindPackageShare
    launch.actions, launch.conditions, launch.substitutions = actions, conditions, subs
    launch_ros.actions, launch_ros.substitutions = ros_actions, ros_subs
    return {"launch": launch, "launch.actions": actions, "launch.conditions": conditions,
            "launch.substitutions": subs, "launch_ros": launch_ros, "launch_ros.actions": ros_actions,
            "launch_ros.substitutions": ros_subs}


def load_launch_description(path: Path = LAUNCH_FILE) -> LaunchDescription:
    """Import the launch file with these implementations and call ``generate_launch_description``."""
    saved = {name: sys.modules.get(name) for name in _modules()}
    sys.modules.update(_modules())
    try:
        spec = importlib.util.spec_from_file_location("canopy_stereo_launch_file", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module.generate_launch_description()
    finally:
        for name, mod in saved.items():
            if mod is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = mod


def evaluate(arguments: dict | None = None, path: Path = LAUNCH_FILE, param_dir: Path | None = None):
    """``ros2 launch canopy_stereo canopy_stereo.launch.py k:=v ...`` -> the node commands
    that would run, and the declared launch arguments (name -> DeclareLaunchArgument)."""
    ld = load_launch_description(path)
    declared = {e.name: e for e in ld.entities if isinstance(e, DeclareLaunchArgument)}
    unknown = set(arguments or {}) - set(declared)
    if unknown:
        raise ValueError(f"launch arguments not declared by {path.name}: {sorted(unknown)}")
    context = LaunchContext({})
    for name, arg in declared.items():
        if name in (arguments or {}):
            context.launch_configurations[name] = str(arguments[name])
        elif arg.default_value is not None:
            context.launch_configurations[name] = perform(arg.default_value, context)
    param_dir = Path(param_dir or tempfile.mkdtemp(prefix="launch_params_"))
    commands = []
    for k, entity in enumerate(e for e in ld.entities if isinstance(e, Node)):
        if entity.condition is not None and not entity.condition.evaluate(context):
            continue
        cmd = NodeCommand(perform(entity.package, context), perform(entity.executable, context),
                          perform(entity.name, context) if entity.name is not None else None)
        cmd.arguments = [perform(a, context) for a in entity.arguments]
        if cmd.name:
            cmd.ros_args += ["-r", f"__node:={cmd.name}"]
        if entity.namespace is not None:
            ns = perform(entity.namespace, context)
            cmd.ros_args += ["-r", f"__ns:={ns if ns.startswith('/') else '/' + ns}"]
        for src, dst in entity.remappings:
            cmd.ros_args += ["-r", f"{perform(src, context)}:={perform(dst, context)}"]
        for j, entry in enumerate(entity.parameters):
            if isinstance(entry, dict):
                values = {perform(key, context): _parameter_value(v, context) for key, v in entry.items()}
                cmd.parameters.update(values)
                path_ = param_dir / f"node{k}_params{j}.yaml"
                path_.write_text(yaml.safe_dump({"/**": {"ros__parameters": values}}))
                cmd.params_files.append(path_)
            else:
                cmd.params_files.append(Path(perform(entry, context)))
        for f in cmd.params_files:
            cmd.ros_args += ["--params-file", str(f)]
        commands.append(cmd)
    return commands, declared


def _parameter_value(value, context):
    """launch_ros (``evaluate_parameter_dict``): a performed substitution is read as YAML and
    must give a scalar or a non-empty list of one type (an empty string, YAML null, is a
    TypeError there: quote it); plain Python values stay."""
    if isinstance(value, (bool, int, float)) or value is None:
        return value
    if isinstance(value, (list, tuple)) and not any(hasattr(v, "perform") for v in value):
        return list(value)
    text = perform(value, context)
    parsed = yaml.safe_load(text)
    if type(parsed) in (bool, int, float, str, bytes):
        return parsed
    if isinstance(parsed, list) and parsed and type(parsed[0]) in (bool, int, float, str) \
            and all(isinstance(v, type(parsed[0])) for v in parsed):
        return parsed
    raise TypeError(f"launch_ros rejects the parameter value {text!r} (YAML {type(parsed).__name__}): "
                    "allowed are bool, int, float, str and non-empty lists of one of them")
