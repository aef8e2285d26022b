"""``canopy-stereo``: one command line over the pure core.

Each subcommand lives in its own module ``canopy_stereo/cli/cmd_<name>.py`` that
defines ``COMMAND`` (the subcommand name), ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``. Modules are discovered
automatically, so adding a subcommand never touches this file.

Errors the user can fix (:class:`~canopy_stereo.errors.CanopyStereoError`,
unreadable files) are printed as one line, ``canopy-stereo <cmd>: error: ...``,
with exit status 2 and no traceback. Set ``CANOPY_STEREO_DEBUG=1`` to see
tracebacks of unexpected failures.
"""
from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from canopy_stereo import __version__
from canopy_stereo.errors import CanopyStereoError


def _commands():
    import canopy_stereo.cli as pkg

    mods = []
    for info in pkgutil.iter_modules(pkg.__path__):
        if not info.name.startswith("cmd_"):
            continue
        try:
            mods.append(importlib.import_module(f"canopy_stereo.cli.{info.name}"))
        except Exception as exc:  # noqa: BLE001 - one broken subcommand must not break the rest
            mods.append(_unavailable(info.name[4:].replace("_", "-"), exc))
    return sorted(mods, key=lambda m: m.COMMAND)


def _unavailable(name: str, exc: Exception):
    """A stand-in subcommand that explains why ``name`` cannot run here."""
    import types

    def run(args):
        raise CanopyStereoError(f"the {name} command is unavailable: {type(exc).__name__}: {exc}")

    return types.SimpleNamespace(COMMAND=name, HELP=f"(unavailable: {exc})",
                                 add_arguments=lambda p: p.add_argument("rest", nargs="*"), run=run)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every discovered subcommand."""
    parser = argparse.ArgumentParser(
        prog="canopy-stereo",
        description="Metric stereo reconstruction and measurement of plant canopies.")
    parser.add_argument("--version", action="version", version=f"canopy-stereo {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for mod in _commands():
        p = sub.add_parser(mod.COMMAND, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``canopy-stereo`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    prog = f"canopy-stereo {args.command}"
    try:
        return _run_command(args, prog)
    finally:
        _forget_caught_interrupts()


def _forget_caught_interrupts() -> None:
    """Clear CPython's "unhandled KeyboardInterrupt" mark before exiting.

    CPython sets that mark whenever an interrupt ends a string ``exec``/``eval``
    (dataclasses, namedtuple and numba build code that way) even when a caller catches
    it, and under ``python -m`` it then exits by SIGINT (status -2) instead of the
    status returned here (130 after Ctrl-C/SIGTERM). Every string eval resets the
    mark first, so an empty one clears it: this function has handled everything.
    """
    exec("", {})  # noqa: S102 - a constant empty string


def _run_command(args, prog: str) -> int:
    try:
        return int(args._run(args) or 0)
    except CanopyStereoError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f" {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"{prog}: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except MemoryError as exc:  # e.g. a rig or image far larger than this machine can hold
        print(f"{prog}: error: not enough memory: {exc or 'allocation failed'}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - last line of defence for users
        if os.environ.get("CANOPY_STEREO_DEBUG"):
            raise
        print(f"{prog}: internal error: {type(exc).__name__}: {exc} "
              "(set CANOPY_STEREO_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
