"""House rule: options are keyword-only on public functions.

A public function or method (name not starting with ``_``, not nested in a function, not
in a private class; dunder methods and node callbacks are private by name) may take at
most two parameters positionally with defaults: every parameter after the first two
(``self``/``cls`` not counted) that has a default value must be keyword-only (after
``*``). Required data parameters may stay positional (``triangulate_dlt(P_left,
P_right, x_left, x_right, *, drop_behind=True)``).
"""
from __future__ import annotations

import ast

from test.conftest import REPO

#: ``(class, function)`` that must keep positional options, each with its reason.
EXEMPT = {
    # overrides rclpy.node.Node.declare_parameters, which rclpy's declare_parameter calls
    # as ``self.declare_parameters('', [args], ignore_override)``
    ("CanopyNode", "declare_parameters"),
}


def positional_options(tree: ast.Module) -> list[tuple[str | None, str, int, list[str]]]:
    """``(class, function, line, options passed positionally)`` of the rule's offenders."""
    found = []

    def visit(node, cls=None):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.ClassDef):
                if not child.name.startswith("_"):
                    visit(child, child)
            elif isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if child.name.startswith("_"):
                    continue  # private, dunder, node callbacks (_on_*)
                positional = child.args.posonlyargs + child.args.args
                static = any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in child.decorator_list)
                bound = cls is not None and not static and positional and positional[0].arg in ("self", "cls")
                skip = 1 if bound else 0
                first_default = len(positional) - len(child.args.defaults)
                bad = [a.arg for i, a in enumerate(positional) if i >= first_default and i - skip >= 2]
                if bad:
                    found.append((cls.name if cls else None, child.name, child.lineno, bad))

    visit(tree)
    return found


def test_options_after_the_second_parameter_are_keyword_only():
    offenders = []
    n_functions = 0
    for path in sorted((REPO / "canopy_stereo").rglob("*.py")):
        tree = ast.parse(path.read_text(), str(path))
        n_functions += sum(isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) for n in ast.walk(tree))
        for cls, name, line, bad in positional_options(tree):
            if (cls, name) not in EXEMPT:
                where = f"{cls}.{name}" if cls else name
                offenders.append(f"{path.relative_to(REPO)}:{line} {where}: make {', '.join(bad)} keyword-only")
    assert n_functions > 500  # the scan saw the package
    assert not offenders, "options passed positionally:\n" + "\n".join(offenders)


def test_the_rule_checker_sees_offenders_and_exemptions():
    src = ("def f(a, b, c=1): pass\n"
           "def g(a, b=1, *, c=2): pass\n"
           "def _h(a, b, c=1): pass\n"
           "class K:\n"
           "    def m(self, a, b, c=1): pass\n"
           "    def n(self, a, b=1, *, c=2): pass\n"
           "    @staticmethod\n"
           "    def s(a, b, c=1): pass\n"
           "    def __init__(self, a, b, c=1): pass\n"
           "def outer(a, b, *, c=1):\n"
           "    def inner(a, b, c=1): pass\n")
    found = {(cls, name): bad for cls, name, _, bad in positional_options(ast.parse(src))}
    assert found == {(None, "f"): ["c"], ("K", "m"): ["c"], ("K", "s"): ["c"]}
