"""docs/results.md's claims tables, generated from ``claims.json`` (``cr_reproduce --write-tables``).

Each chapter with claims gets one block in docs/results.md between two marker comments::

    <!-- claims:begin chapter=3 -->
    | claim | measured | verdict |
    ...
    <!-- claims:end chapter=3 -->

rendered by :func:`block` from the chapter's claims (generic: every claim of the chapter, in
the order of claims.json, so a chapter added to ``cr_reproduce`` appears without code here).
The numbers come from ``cr_reproduce --quick`` (deterministic: the same numbers for any
number of workers, and on every machine to the digits printed), which is what CI runs;
``--check`` fails when a block differs from what the claims give, is missing, or belongs to
a chapter without claims.

A diverged run (``status = diverged``: it grew until a guard stopped it) is printed to
:data:`DIVERGED_DIGITS` significant digits: how far it had grown is its machine's
floating-point history amplified. Case 5 of chapter 4 ended with ss_error_N = 797.3 on
the machines that wrote these tables and 796.3 on an AMD EPYC with AVX-512 (2026-11-26),
the same code and the same stop at t = 51.261 s; any run that does not diverge agreed to
every digit.

    python -m cr_control.experiments.results_tables CLAIMS.json --write docs/results.md
    python -m cr_control.experiments.results_tables CLAIMS.json --check docs/results.md

(``cr_reproduce --quick --out DIR --write-tables docs/results.md`` does the first after the
run.) A missing block is inserted at the end of the section whose ``## `` heading names the
chapter ("Chapter 4", "appendix C"), or in a new section at the end of the file.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

BEGIN = "<!-- claims:begin chapter={} -->"
END = "<!-- claims:end chapter={} -->"
MARKER = re.compile(r"<!-- claims:(begin|end) chapter=(\w+) -->")
#: How a measured float is printed (significant digits): enough to see any change.
DIGITS = 4
#: ... and one of a diverged run (module docstring).
DIVERGED_DIGITS = 2
ORDER = ["2", "3", "4", "5", "6", "C"]


def _value(value: Any, digits: int = DIGITS) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v, digits) for v in value) + "]"
    return str(value)


def _cell(text: str) -> str:
    """Markdown table cell: pipes escaped, one line."""
    return " ".join(text.replace("|", "\\|").split())


def chapters(claims: list[dict[str, Any]]) -> list[str]:
    """The chapters of ``claims``, in thesis order (unknown names after, sorted)."""
    found = {str(c["chapter"]) for c in claims}
    return [c for c in ORDER if c in found] + sorted(found - set(ORDER))


def block(claims: list[dict[str, Any]], chapter: str) -> str:
    """The generated block of ``chapter``: a table of claim, measured and verdict."""
    lines = [BEGIN.format(chapter), "| claim | measured | verdict |", "|---|---|---|"]
    for c in claims:
        if str(c["chapter"]) != chapter:
            continue
        digits = DIVERGED_DIGITS if c["measured"].get("status") == "diverged" else DIGITS
        measured = "; ".join(f"{k} = {_value(v, digits)}" for k, v in c["measured"].items())
        lines.append(f"| {_cell(c['claim'])} | {_cell(measured)} | **{_cell(c['verdict'])}** |")
    lines.append(END.format(chapter))
    return "\n".join(lines)


def blocks_in(text: str) -> dict[str, str]:
    """The generated blocks of ``text`` by chapter (ValueError on unbalanced markers)."""
    out: dict[str, str] = {}
    open_at: tuple[str, int] | None = None
    for m in MARKER.finditer(text):
        kind, chapter = m.group(1), m.group(2)
        if kind == "begin":
            if open_at is not None or chapter in out:
                raise ValueError(f"claims block of chapter {chapter}: nested or repeated")
            open_at = (chapter, m.start())
        else:
            if open_at is None or open_at[0] != chapter:
                raise ValueError(f"claims:end chapter={chapter} without its begin")
            out[chapter] = text[open_at[1]:m.end()]
            open_at = None
    if open_at is not None:
        raise ValueError(f"claims block of chapter {open_at[0]} is not closed")
    return out


def differences(claims: list[dict[str, Any]], text: str) -> list[str]:
    """What in ``text`` disagrees with ``claims`` (one line each; empty when they agree)."""
    present = blocks_in(text)
    out = []
    for chapter in chapters(claims):
        if chapter not in present:
            out.append(f"chapter {chapter}: no generated claims block")
        elif present[chapter] != block(claims, chapter):
            out.append(f"chapter {chapter}: the claims block differs from claims.json")
    out += [f"chapter {c}: a claims block but no claims" for c in present
            if c not in chapters(claims)]
    return out


def _heading_pattern(chapter: str) -> re.Pattern[str]:
    if chapter.isdigit():
        return re.compile(rf"^## .*\bchapter {chapter}\b", re.IGNORECASE)
    return re.compile(rf"^## .*\bappendix {chapter}\b", re.IGNORECASE)


def write(claims: list[dict[str, Any]], text: str) -> str:
    """``text`` with every chapter's block replaced or inserted, stale blocks removed."""
    present = blocks_in(text)
    for chapter, old in present.items():
        new = block(claims, chapter) if chapter in chapters(claims) else ""
        text = text.replace(old + ("\n\n" if not new and old + "\n\n" in text else ""), new)
    for chapter in chapters(claims):
        if chapter in present:
            continue
        lines = text.rstrip("\n").split("\n")
        pattern = _heading_pattern(chapter)
        at = next((i for i, line in enumerate(lines) if pattern.search(line)), None)
        if at is None:
            lines += ["", f"## Chapter {chapter} (claims)", "", block(claims, chapter)]
        else:
            end = next((i for i in range(at + 1, len(lines)) if lines[i].startswith("## ")),
                       len(lines))
            while end > at + 1 and not lines[end - 1].strip():
                end -= 1
            lines[end:end] = ["", block(claims, chapter)]
        text = "\n".join(lines) + "\n"
    return text


def load(path: Path) -> list[dict[str, Any]]:
    """claims.json's entries (ValueError with one line when it is not a claims list)."""
    try:
        items = json.loads(Path(path).read_text())
    except OSError as exc:
        raise ValueError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not JSON: {exc.msg} (line {exc.lineno})") from None
    keys = {"chapter", "claim", "measured", "verdict"}
    if not isinstance(items, list) or not all(isinstance(c, dict) and keys <= c.keys()
                                              and isinstance(c["measured"], dict)
                                              for c in items):
        raise ValueError(f"{path}: not a claims list (entries with {', '.join(sorted(keys))})")
    return items


def main(argv: Iterable[str] | None = None) -> int:
    """Write or check docs/results.md's generated claims tables; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m cr_control.experiments.results_tables",
                                     description="docs/results.md's claims tables from "
                                     "cr_reproduce's claims.json.")
    parser.add_argument("claims", type=Path, metavar="CLAIMS.json")
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", type=Path, metavar="RESULTS.md")
    mode.add_argument("--check", type=Path, metavar="RESULTS.md")
    args = parser.parse_args(None if argv is None else list(argv))
    target = args.write or args.check
    try:
        claims = load(args.claims)
        text = target.read_text()
        if args.write:
            target.write_text(write(claims, text))
            print(f"wrote the claims tables of chapters {', '.join(chapters(claims))} "
                  f"into {target}")
            return 0
        wrong = differences(claims, text)
    except OSError as exc:
        print(f"results_tables: error: {target}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"results_tables: error: {exc}", file=sys.stderr)
        return 2
    for line in wrong:
        print(f"{target}: {line}", file=sys.stderr)
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
