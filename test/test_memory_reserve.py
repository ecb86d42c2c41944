"""The pre-faulted heap (nodes/memory_reserve.py): 64 MiB by default, sized by its
environment variable; on glibc it is set up without error in a process of its own, and
with one malloc arena (what sessions set) it serves another thread's allocation too."""

import os
import subprocess
import sys

import pytest

from cr_control.nodes import memory_reserve


@pytest.mark.parametrize("text, mib", [("", memory_reserve.DEFAULT_RESERVE_MB), ("0", 0),
                                       ("32", 32), ("-3", 0), ("x", 0), ("99999", 4096)])
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


def test_sessions_ask_for_one_arena_unless_told_otherwise():
    assert memory_reserve.loop_env({}) == {memory_reserve.ARENA_VARIABLE: "1"}
    none = {memory_reserve.RESERVE_VARIABLE: "0"}
    assert memory_reserve.loop_env(dict(none)) == none                  # no reserve: no arena
    mine = {memory_reserve.ARENA_VARIABLE: "4"}
    assert memory_reserve.loop_env(dict(mine)) == mine                  # the user's stays


@pytest.mark.parametrize("arenas, bound", [("1", (0, 64)), (None, (256, 1 << 30))],
                         ids=["one-arena", "glibc-default"])
def test_with_one_arena_the_reserve_serves_another_thread(arenas, bound):
    """A thread started after the reserve (the parameter gate's) allocates 16 MiB: with one
    arena its pages come from the reserve; with glibc's arenas per thread they fault in
    (each fault 5-40 us here: the 8 MB request's 9-16 ms)."""
    code = (
        "import resource, threading, numpy as np\n"
        "from cr_control.nodes import memory_reserve\n"
        "threading.Thread(target=lambda: np.ones(1 << 20)).start()   # a thread with an arena\n"
        "assert memory_reserve.reserve(32 << 20) is None\n"
        "out = []\n"
        "def work():\n"
        "    before = resource.getrusage(resource.RUSAGE_THREAD).ru_minflt\n"
        "    a = np.ones(16 << 20, np.uint8)\n"
        "    out.append(resource.getrusage(resource.RUSAGE_THREAD).ru_minflt - before)\n"
        "t = threading.Thread(target=work); t.start(); t.join()\n"
        "print(out[0])\n")
    env = {k: v for k, v in os.environ.items() if k != memory_reserve.ARENA_VARIABLE}
    if arenas:
        env[memory_reserve.ARENA_VARIABLE] = arenas
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, env=env)
    assert got.returncode == 0, got.stderr
    assert bound[0] <= int(got.stdout.strip()) < bound[1]
