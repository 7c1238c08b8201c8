"""The package structure holds: no import cycle between packages (lazy imports inside
functions included: they are cycles at run time), nothing outside ``commands/`` and
``cli.py`` imports ``motionphysics.commands``, and nothing below the top imports
``motionphysics.pipeline``."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src" / "motionphysics"


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> list[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    me = _module_name(path)
    package = me if path.name == "__init__.py" else me.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            out.append(mod)
            # ``from motionphysics import optimize`` imports a package, not a name
            out += [
                f"{mod}.{a.name}"
                for a in node.names
                if (SRC.parent / mod.replace(".", "/") / a.name).exists()
            ]
    return [m for m in out if m == "motionphysics" or m.startswith("motionphysics.")]


def _node(module: str) -> str:
    """The unit of the package graph: a sub-package, or a top-level module."""
    parts = module.split(".")
    return ".".join(parts[:2]) if len(parts) > 1 else parts[0]


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {}
    for path in SRC.rglob("*.py"):
        src = _node(_module_name(path))
        for mod in _imports(path):
            dst = _node(mod)
            if dst != src and dst != "motionphysics":
                graph.setdefault(src, set()).add(dst)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_walker_sees_real_edges():
    g = _graph()
    assert "motionphysics.sim" in g["motionphysics.assembly"]
    assert "motionphysics.assembly" in g["motionphysics.optimize"]
    # a cycle planted in a copy of the graph is found
    planted = {k: set(v) for k, v in g.items()}
    planted.setdefault("motionphysics.sim", set()).add("motionphysics.assembly")
    assert any("motionphysics.sim" in c for c in _cycles(planted))


def test_no_import_cycle_between_packages():
    cycles = _cycles(_graph())
    assert not cycles, f"import cycles between packages: {cycles}"


def test_commands_and_pipeline_are_imported_only_from_above():
    bad = []
    for path in SRC.rglob("*.py"):
        me = _module_name(path)
        for mod in _imports(path):
            in_commands = me.startswith("motionphysics.commands") or me == "motionphysics.cli"
            if mod.startswith("motionphysics.commands") and not in_commands:
                bad.append(f"{me} imports {mod}")
            if mod == "motionphysics.pipeline" and not (
                in_commands or me == "motionphysics.pipeline"
            ):
                bad.append(f"{me} imports {mod}")
    assert not bad, bad
