"""YAML values as ROS reads them: ``1e12`` is a number, not a string.

PyYAML implements YAML 1.1, where a float needs a dot in its mantissa, so ``1e12`` or
``[1e12, 2e-3]`` load as strings; ROS's params-file parser and YAML 1.2 read them as
floats. Every tool of this package that turns user text into parameter values loads it
with :func:`load`, and reads a YAML file with :func:`read_file`.

Hostile or careless input is refused in one line, in bounded time and memory: aliases
(``*name``) are refused, since nested ones expand exponentially (ten lines of them stand
for 10^9 values, the "billion laughs"), nesting is at most MAX_DEPTH deep, and a file is
read only if it is a regular file of at most MAX_FILE_BYTES (a named pipe would block the
reader for ever, ``/dev/zero`` fill its memory).
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml
from yaml.composer import ComposerError

#: Largest YAML file read (bytes): a SPEC or a params file is a few kB.
MAX_FILE_BYTES = 1 << 20
#: Deepest nesting of sequences and mappings (a parameter is a matrix at most).
MAX_DEPTH = 64


class _RosLoader(yaml.SafeLoader):
    """SafeLoader that also takes exponent-only floats (``1e12``, ``-2E-3``) as floats, and
    refuses aliases and nesting deeper than MAX_DEPTH (a ComposerError, a yaml.YAMLError)."""

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            raise ComposerError(None, None, f"alias *{event.anchor[:40]} refused: aliases are not "
                                "accepted, write the value out", event.start_mark)
        if self._depth >= MAX_DEPTH:
            raise ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels",
                                event.start_mark)
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_RosLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def load(text: str) -> Any:
    """``text`` parsed as YAML (yaml.YAMLError if it is not)."""
    return yaml.load(text, Loader=_RosLoader)  # noqa: S506 - a SafeLoader subclass


def read_file(path: str | Path, limit: int = MAX_FILE_BYTES) -> str:
    """The text of the file at ``path``. ValueError (one line, without the path) unless it
    is a regular file of at most ``limit`` bytes of UTF-8 text; OSError if it cannot be
    opened or read."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)   # a named pipe: opened without waiting
    try:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise ValueError("is a directory, not a file")
        if not stat.S_ISREG(mode):
            raise ValueError("not a regular file (a pipe, device or socket)")
        with os.fdopen(fd, "rb", closefd=False) as f:
            data = f.read(limit + 1)
    finally:
        os.close(fd)
    if len(data) > limit:
        raise ValueError(f"larger than {_size(limit)}, the limit for a YAML file here")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"not UTF-8 text (byte {exc.start})") from None


def _size(n: int) -> str:
    return f"{n >> 20} MiB" if n % (1 << 20) == 0 else f"{n} bytes"


def describe_error(exc: yaml.YAMLError) -> str:
    """A one-line account of a YAML error: the problem and where it is."""
    problem = getattr(exc, "problem", None) or (str(exc).splitlines() or [""])[0]
    if len(problem) > 120:
        problem = problem[:117] + "..."
    mark = getattr(exc, "problem_mark", None)
    where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
    return f"{problem}{where}"


#: What a ROS params file holds, for messages.
PARAMS_FILE_FORM = "NODE: {ros__parameters: {NAME: VALUE, ...}}"


def is_empty_params(data: Any) -> bool:
    """True for a loaded params file that names no node at all: an empty file, only
    comments, ``{}``, ``null`` or ``~``. rcl takes such a file without a word, so a
    mistyped or truncated file would pass unnoticed; we refuse it."""
    return data is None or data == {}


def empty_params_file(path: str) -> bool:
    """True if the file at ``path`` reads as an empty params file (:func:`is_empty_params`);
    False if it holds something, or cannot be read or parsed (its reader says why)."""
    try:
        with open(path, encoding="utf-8") as f:
            return is_empty_params(load(f.read()))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return False
