"""YAML values as ROS reads them: ``1e12`` is a number, not a string.

PyYAML implements YAML 1.1, where a float needs a dot in its mantissa, so ``1e12`` or
``[1e12, 2e-3]`` load as strings; ROS's params-file parser and YAML 1.2 read them as
floats. Every tool of this package that turns user text into parameter values loads it
with :func:`load`.
"""

from __future__ import annotations

import re
from typing import Any

import yaml


class _RosLoader(yaml.SafeLoader):
    """SafeLoader that also takes exponent-only floats (``1e12``, ``-2E-3``) as floats."""


_RosLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def load(text: str) -> Any:
    """``text`` parsed as YAML (yaml.YAMLError if it is not)."""
    return yaml.load(text, Loader=_RosLoader)  # noqa: S506 - a SafeLoader subclass


def describe_error(exc: yaml.YAMLError) -> str:
    """A one-line account of a YAML error: the problem and where it is."""
    problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
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
