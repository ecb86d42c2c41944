"""Finished points, persisted as they finish, so that a sweep resumes where it stopped.

``DIR/sweep.json`` records the SPEC (and its digest); ``DIR/points.jsonl`` holds one JSON
line per finished point: its index, its inputs and its result. Each batch of lines is
flushed and fsync'ed when it arrives, so a killed sweep loses only the points in flight; a
line cut short by the kill is ignored on the next run. Floats go through JSON as Python
writes them (shortest repr, NaN and Infinity kept), so they read back bit for bit.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from cr_control.experiments.spec import SpecError, SweepSpec

SPEC_FILE = "sweep.json"
POINTS_FILE = "points.jsonl"


class Store:
    """The finished points of one sweep in ``out`` (see the module docstring)."""

    def __init__(self, out: Path, spec: SweepSpec):
        """Open (create) ``out`` for ``spec``; SpecError if ``out`` holds another sweep."""
        self.out = Path(out)
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise SpecError(f"--out {out}: cannot create: {exc.strerror or exc}") from None
        if not os.access(self.out, os.W_OK | os.X_OK):
            raise SpecError(f"--out {out}: no permission to write there")
        record = {"digest": spec.digest(), "spec": spec.canonical()}
        path = self.out / SPEC_FILE
        if path.exists():
            try:
                old = json.loads(path.read_text())
            except (OSError, ValueError):
                old = None
            if not isinstance(old, dict) or old.get("digest") != record["digest"]:
                raise SpecError(f"--out {out} holds another sweep ({SPEC_FILE} differs): give a "
                                "new directory, or delete it to start over")
        path.write_text(json.dumps(record, indent=2) + "\n")
        self._file = None

    def finished(self) -> dict[int, dict[str, Any]]:
        """Index -> record of every finished point on disk (a cut-short line is ignored)."""
        path = self.out / POINTS_FILE
        done: dict[int, dict[str, Any]] = {}
        if not path.exists():
            return done
        with open(path) as f:
            for line in f:
                try:
                    record = json.loads(line)
                except ValueError:
                    continue
                if isinstance(record, dict) and isinstance(record.get("point"), int) \
                        and line.endswith("\n"):
                    done[record["point"]] = record
        return done

    def add(self, records: list[dict[str, Any]]) -> None:
        """Append finished points, on disk before this returns."""
        if self._file is None:
            path = self.out / POINTS_FILE
            self._file = open(path, "a")  # noqa: SIM115 - closed by close()
            if path.stat().st_size:     # a line cut short by a kill: end it, it is ignored
                with open(path, "rb") as f:
                    f.seek(-1, os.SEEK_END)
                    if f.read(1) != b"\n":
                        self._file.write("\n")
        for record in records:
            self._file.write(json.dumps(record) + "\n")
        self._file.flush()
        os.fsync(self._file.fileno())

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
