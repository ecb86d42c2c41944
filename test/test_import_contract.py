"""The package's layers, checked (docs/architecture.md): the import contracts of
``.importlinter`` hold (``lint-imports``), no two modules import each other through any
chain (function-level imports included, so none can hide a cycle), reading a recorded
session loads no control law or plant, and docs/architecture.md names every package."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("cr_control", "cr_sim")


def modules() -> dict[str, Path]:
    """Dotted name -> file of every module of the two packages."""
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def import_graph(files: dict[str, Path]) -> dict[str, set[str]]:
    """module -> the project modules it imports anywhere in its file (top level or inside a
    function), each import resolved to the longest module name it starts with."""

    def resolve(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets: list[str] = []
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets += [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parts = package.split(".")[:len(package.split(".")) - node.level + 1]
                    base = ".".join(parts + ([base] if base else []))
                targets += [f"{base}.{a.name}" for a in node.names]
        graph[name] = {m for m in map(resolve, targets) if m and m != name}
    return graph


def cycles(graph: dict[str, Iterable[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_cycle_finder_finds_a_cycle_through_a_chain():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}, "e": set()}
    assert cycles(graph) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules():
    files = modules()
    graph = import_graph(files)
    assert len(graph) > 150 and "cr_control.offline.loop" in graph["cr_control.offline.build"]
    assert cycles(graph) == []


def test_the_import_contracts_hold():
    config = ROOT / ".importlinter"
    contracts = config.read_text().count("[importlinter:contract:")
    result = subprocess.run([str(Path(sys.executable).parent / "lint-imports"), "--config",
                             str(config), "--no-cache"], cwd=ROOT, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stdout[-6000:] + result.stderr[-3000:]
    assert f"Contracts: {contracts} kept, 0 broken." in result.stdout, result.stdout[-3000:]


def test_reading_a_session_loads_no_control_law_or_plant():
    """cr_analyze's import: the chapter analyses import the offline runner, the laws and the
    plants inside the functions that run them, so reading a recording compiles nothing."""
    probe = ("import sys, cr_control.analysis.analyze, cr_control.analysis.plots; "
             "print(sorted(m for m in sys.modules if m.startswith(('cr_control.schemes', "
             "'cr_control.offline', 'cr_sim', 'numba', 'rclpy'))))")
    result = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True,
                            text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-3000:]
    assert result.stdout.strip() == "[]"


def test_architecture_doc_names_every_package():
    """Every package (a folder with __init__.py) as ``name/`` and every module at the top of
    cr_control and cr_sim as ``name.py``; every ``name/`` the layout block names exists."""
    doc = (ROOT / "docs" / "architecture.md").read_text()
    packages = sorted({p.parent for p in (ROOT / "cr_control").rglob("__init__.py")}
                      | {p.parent for p in (ROOT / "cr_sim").rglob("__init__.py")})
    missing = [str(p.relative_to(ROOT)) for p in packages
               if p.name not in PACKAGES and f"{p.name}/" not in doc]
    missing += [f"{package}/{p.name}" for package in PACKAGES
                for p in (ROOT / package).glob("*.py")
                if p.name != "__init__.py" and p.name not in doc]
    assert missing == []
    layout = doc.split("## Packages", 1)[1].split("```")[1]
    named = set(re.findall(r"^\s*([a-z_]+)/", layout, re.M))
    existing = {p.name for p in packages} | {"config"}
    assert named and named <= existing, named - existing
