"""The exit status the CLI returns is the one the shell sees, also under ``python -m``."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from test.conftest import REPO

#: a package whose ``__main__`` runs the real CLI with one subcommand replaced
_MAIN = textwrap.dedent("""
    import sys

    import canopy_stereo.cli.cmd_simulate as cmd

    def interrupted_inside_generated_code(args):
        exec({code!r}, {{}})  # as when Ctrl-C/SIGTERM lands while a dataclass is being built

    cmd.run = interrupted_inside_generated_code
    from canopy_stereo.cli import main

    sys.exit(main(["simulate", "croton", "-o", "out"]))
""")


@pytest.mark.parametrize("code, status", [
    ("raise KeyboardInterrupt", 130),  # interrupted: 130, not death by SIGINT (-2)
    ("pass", 0),
])
def test_python_m_exit_status_survives_interrupts_caught_in_generated_code(tmp_path, code, status):
    """CPython marks an interrupt that ends a string ``exec`` as unhandled even when the CLI
    catches it; ``python -m`` then used to die by SIGINT (-2) instead of exiting 130."""
    pkg = tmp_path / "interrupted_cli"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "__main__.py").write_text(_MAIN.format(code=code))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), str(REPO)]))
    env.pop("CANOPY_STEREO_DEBUG", None)
    out = subprocess.run([sys.executable, "-m", "interrupted_cli"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == status, out.stderr
    if status == 130:
        assert out.stderr.strip() == "canopy-stereo simulate: interrupted"
