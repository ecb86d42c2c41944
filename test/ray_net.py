"""Helpers of the Ray tests: process trees and the TCP sockets ``ss`` shows for them."""

from __future__ import annotations

import subprocess
from pathlib import Path


def _children() -> dict[int, list[int]]:
    out = subprocess.run(["ps", "-eo", "pid=,ppid="], capture_output=True, text=True).stdout
    kids: dict[int, list[int]] = {}
    for line in out.splitlines():
        pid, ppid = map(int, line.split())
        kids.setdefault(ppid, []).append(pid)
    return kids


def tree(roots: list[int]) -> set[int]:
    kids, seen, stack = _children(), set(), list(roots)
    while stack:
        pid = stack.pop()
        if pid not in seen:
            seen.add(pid)
            stack += kids.get(pid, [])
    return seen


def with_cmdline(text: str) -> list[int]:
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


def non_loopback(pids: set[int]) -> tuple[list[str], int]:
    """Connections of ``pids`` through a non-loopback address; their wildcard listeners."""
    out = subprocess.run(["ss", "-tanpH"], capture_output=True, text=True).stdout
    bad, wildcard = [], 0
    for line in out.splitlines():
        fields = line.split()
        if len(fields) < 6 or not any(f"pid={p}," in fields[-1] for p in pids):
            continue
        state, local, peer = fields[0], fields[3], fields[4]
        if state == "LISTEN":
            wildcard += local.startswith(("*:", "0.0.0.0:", "[::]:"))
            continue
        for address in (local, peer):
            host = address.rsplit(":", 1)[0].strip("[]").removeprefix("::ffff:")
            if not host.startswith("127."):
                bad.append(line)
    return bad, wildcard
