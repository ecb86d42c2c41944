"""The pre-faulted heap (nodes/memory_reserve.py): opt-in by its environment variable, and
on glibc it is set up without error in a process of its own."""

import subprocess
import sys

import pytest

from cr_control.nodes import memory_reserve


@pytest.mark.parametrize("text, mib", [("", 0), ("0", 0), ("64", 64), ("-3", 0), ("x", 0),
                                       ("99999", 4096)])
def test_the_reserve_is_what_the_variable_asks_for(monkeypatch, text, mib):
    monkeypatch.setenv(memory_reserve.RESERVE_VARIABLE, text)
    assert memory_reserve.reserve_bytes() == mib << 20


def test_a_reserve_is_set_up_and_a_large_buffer_reuses_it():
    """In a fresh process: reserve() succeeds, and a 16 MiB buffer allocated afterwards
    faults no page in (its pages come from the reserve)."""
    code = (
        "import resource, numpy as np\n"
        "from cr_control.nodes import memory_reserve\n"
        "assert memory_reserve.reserve(32 << 20) is None\n"
        "before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        "a = np.ones(16 << 20, np.uint8)\n"
        "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n")
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert got.returncode == 0, got.stderr
    assert int(got.stdout.strip()) < 64          # 16 MiB of fresh pages would be 4096 faults
