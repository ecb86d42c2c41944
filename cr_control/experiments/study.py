"""A study of ``cr_reproduce``: one sweep named for the thesis section it reproduces, and
how a claim finds a row of its results.

The chapter modules (:mod:`.chapters_246c`, :mod:`.normalised_gradient`,
:mod:`.panda_map`) build their studies and read their rows with this module alone, so
:mod:`.reproduce` imports them and none of them imports :mod:`.reproduce`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from cr_control.experiments.sweep import SweepResult


@dataclass
class Study:
    """One sweep of the report: ``spec`` as :func:`cr_control.experiments.spec.parse_spec`
    reads it, shown under ``chapter`` with ``title``."""

    name: str
    chapter: str
    title: str
    spec: dict[str, Any]


def row(result: SweepResult, **inputs: Any) -> dict[str, Any]:
    """The row of ``result`` whose inputs are ``inputs`` (node.param with '.' as '__')."""
    wanted = {k.replace("__", "."): v for k, v in inputs.items()}
    for r in result.rows:
        if all(r.get(k) == v for k, v in wanted.items()):
            return r
    raise KeyError(wanted)
