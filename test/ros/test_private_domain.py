"""Private DDS domains: concurrent test sessions and benchmarks on one machine never share
one (canopy_stereo.ros.context.private_domain_id)."""
from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("rclpy")
from canopy_stereo.ros.context import PRIVATE_DOMAIN_BASE, private_domain_id  # noqa: E402

#: a process whose pid (as the module sees it) is 4242, printing its domain and holding it until stdin closes
HOLDER = ("import os; os.getpid = lambda: 4242\n"
          "from canopy_stereo.ros.context import private_domain_id\n"
          "print(private_domain_id(), private_domain_id(), flush=True)\n"
          "import sys; sys.stdin.read()\n")


def test_processes_with_the_same_derived_id_get_different_domains():
    procs = [subprocess.Popen([sys.executable, "-c", HOLDER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True) for _ in range(3)]
    try:
        seen = []
        for p in procs:  # one after the other: each reserves while the earlier ones hold theirs
            first, again = (int(v) for v in p.stdout.readline().split())
            assert first == again  # a process keeps its domain
            seen.append(first)
    finally:
        for p in procs:
            p.communicate("")
    assert len(set(seen)) == 3 and all(PRIVATE_DOMAIN_BASE <= d < PRIVATE_DOMAIN_BASE + 100 for d in seen)
    # released at exit: the next process gets the first free one from the derived 142 on again
    first_free = min(seen, key=lambda d: (d - PRIVATE_DOMAIN_BASE - 42) % 100)
    out = subprocess.run([sys.executable, "-c", HOLDER], input="", capture_output=True, text=True, check=True)
    assert out.stdout.split()[0] == str(first_free)


def test_explicit_pid_is_the_derived_id():
    assert private_domain_id(4242) == PRIVATE_DOMAIN_BASE + 42
    assert private_domain_id() == private_domain_id()
