"""Call executables' ``main(argv)`` one after another in one process, each with its output
(file descriptors 1 and 2: Python's and C's) captured: many bad command lines at the cost of
one interpreter start. ``python -m test.support.run_mains CALLS.json`` where the file holds
``[[module, [argv...]], ...]``; prints a JSON list of ``{"status": exit status, "output": text}``
(a traceback escaping ``main`` gives status ``"raised"``)."""
from __future__ import annotations

import importlib
import json
import os
import sys
import tempfile
import traceback


def call(module: str, argv: list[str]) -> dict:
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile() as out:
        os.dup2(out.fileno(), 1)
        os.dup2(out.fileno(), 2)
        try:
            status = importlib.import_module(module).main(argv)
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 1
        except BaseException:  # noqa: BLE001 - reported to the test
            traceback.print_exc()
            status = "raised"
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
        out.seek(0)
        return {"status": status, "output": out.read().decode("utf-8", "replace")}


def main() -> None:
    with open(sys.argv[1], encoding="utf-8") as f:
        calls = json.load(f)
    results = [call(module, argv) for module, argv in calls]
    print(json.dumps(results))


if __name__ == "__main__":
    main()
