"""A progress bar with ETA on stderr: redrawn in place on a terminal, a line per update
(at most one every few seconds) otherwise, e.g. in CI logs."""

from __future__ import annotations

import sys
import time
from typing import TextIO

#: Seconds between lines when stderr is not a terminal.
LINE_EVERY_S = 5.0
WIDTH = 30


def _clock(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


class Progress:
    """``total`` points of which ``skipped`` were done before; ETA from this run's rate."""

    def __init__(self, total: int, skipped: int = 0, label: str = "points",
                 stream: TextIO | None = None):
        self.total, self.done, self.skipped, self.label = total, skipped, skipped, label
        self.stream = stream or sys.stderr
        self.tty = self.stream.isatty()
        self.start = time.monotonic()
        self._last_line = -LINE_EVERY_S
        self.draw()

    def text(self) -> str:
        """``[#####.....]  12/40 points  00:31 elapsed  ETA 01:12``"""
        elapsed = time.monotonic() - self.start
        fraction = self.done / self.total if self.total else 1.0
        filled = int(WIDTH * fraction)
        new = self.done - self.skipped
        left = self.total - self.done
        eta = _clock(elapsed / new * left) if new and left else ("--:--" if left else "00:00")
        return (f"[{'#' * filled}{'.' * (WIDTH - filled)}] {self.done}/{self.total} "
                f"{self.label}  {_clock(elapsed)} elapsed  ETA {eta}")

    def advance(self, count: int) -> None:
        self.done += count
        self.draw()

    def draw(self, final: bool = False) -> None:
        now = time.monotonic()
        if self.tty:
            self.stream.write("\r" + self.text() + ("\n" if final else ""))
        elif final or now - self._last_line >= LINE_EVERY_S or self.done == self.total:
            self.stream.write(self.text() + "\n")
            self._last_line = now
        self.stream.flush()

    def close(self) -> None:
        if self.tty:
            self.draw(final=True)
