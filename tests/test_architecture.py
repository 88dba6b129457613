"""The layers of docs/DESIGN.md, held against the code: imports point down, no cycles, one place builds simulators.

The import graph is read from the source (``ast``), module-level and function-level imports alike (a lazy
import is still a dependency); imports under ``if TYPE_CHECKING:`` are annotations only and do not count.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "proxybench"

#: docs/DESIGN.md §2, bottom up: a module may import from its own package and from packages of a lower rank
RANKS = {
    "untrusted": 0, "messages": 0, "media": 0, "lazy": 0, "venv": 0, "private": 0, "__init__": 0,
    "domain": 1,
    "agents": 2,
    "protocol": 3,
    "dtps": 3.5,  # SDK agents over DTPS: above protocol (its process machinery), below tasks and runner
    "tasks": 4,
    "runner": 5, "usefulness": 5, "plots": 5, "gym": 5,
    "learning": 5.5,  # behaviour cloning asks the runner's engine to drive robots (collection, scoring)
    "targets": 6, "testing": 6, "contract": 6,
    "client": 7, "autolab": 7,
    "server": 8, "evaluator": 8,
    "experiments": 9,
    "cli": 10, "__main__": 11,
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(SRC.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in SRC.rglob("*.py") if "migrations" not in p.parts}


def _imports(path: Path, name: str, known: set[str], type_only: bool = False) -> set[str]:
    """The proxybench modules ``path`` imports (resolved to the longest known module), TYPE_CHECKING aside (or,
    with ``type_only``, included: annotations are dependencies of a reader too)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()

    def resolve(dotted: str) -> str | None:
        while dotted and dotted not in known:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test) and not type_only:
                for sub in child.orelse:
                    visit(sub)
                continue
            if isinstance(child, ast.Import):
                targets = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    up = package.split(".")[: len(package.split(".")) - (child.level - 1)]
                    base = ".".join(up + ([base] if base else []))
                targets = [f"{base}.{a.name}" for a in child.names]
            else:
                visit(child)
                continue
            for t in targets:
                r = resolve(t) if t.startswith("proxybench") else None
                if r and r != name:
                    out.add(r)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    return {name: _imports(path, name, set(mods)) for name, path in mods.items()}


def _top(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def test_every_package_has_a_layer(graph):
    unranked = {_top(m) for m in graph} - set(RANKS)
    assert not unranked, f"new top-level modules or packages {unranked}: give each a rank here and in docs/DESIGN.md"


def test_imports_point_down_the_layers(graph):
    up = sorted(f"{a} -> {b}" for a, deps in graph.items() for b in deps
                if _top(a) != _top(b) and RANKS[_top(b)] >= RANKS[_top(a)])
    assert not up, "imports that point up (or sideways) the layers of docs/DESIGN.md:\n" + "\n".join(up)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return cycles


def test_no_import_cycles(graph):
    assert not _cycles(graph), f"import cycles: {_cycles(graph)}"


def test_no_import_cycles_even_through_annotations():
    """Issue 33: not even a type-only circle (an ``if TYPE_CHECKING:`` import back): a reader follows those too."""
    mods = _modules()
    full = {name: _imports(path, name, set(mods), type_only=True) for name, path in mods.items()}
    assert not _cycles(full), f"import cycles through annotations: {_cycles(full)}"


#: a script gym-duckietown's interpreter runs: the Simulator it builds is gym's, not proxybench's
GYM_BRIDGE = SRC / "gym" / "bridge.py"


def test_only_the_runner_builds_simulators():
    """Episodes run in one place: no ``Simulator(`` outside domain/ (its home) and runner/ (the engine)."""
    found = []
    for path in SRC.rglob("*.py"):
        if _top(_module_name(path)) in ("domain", "runner") or path == GYM_BRIDGE:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", None)) == "Simulator":
                found.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not found, "Simulator built outside domain/ and runner/: " + ", ".join(found)


def test_usefulness_holds_pure_measures(graph):
    """usefulness/ is the thesis' measures as functions of paired tables: nothing above tasks/."""
    bad = sorted(f"{a} -> {b}" for a, deps in graph.items() if _top(a) == "usefulness" for b in deps
                 if _top(b) not in ("usefulness", "tasks", "__init__"))
    assert not bad, "\n".join(bad)
