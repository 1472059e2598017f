"""The template package's import graph, read from the source with ast: no loops among its modules, no
import of graspd.sim, and the outcome store and database below it (they never import graspd.templates)."""

from __future__ import annotations

import ast
from pathlib import Path

import graspd

PACKAGE = Path(graspd.__file__).parent


def module_name(path: Path) -> str:
    """graspd.x.y of a source file under the graspd package."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_of(path: Path) -> set[str]:
    """Every graspd module path imports (anywhere in the file), as absolute names; `from p import n` counts
    as p and, when p.n is a module, p.n."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    known = {module_name(p) for p in PACKAGE.rglob("*.py")}
    return {m for m in out if m in known and m != name}


def graph(modules: list[Path]) -> dict[str, set[str]]:
    return {module_name(p): imports_of(p) for p in modules}


def find_cycle(edges: dict[str, set[str]]) -> list[str] | None:
    """One import loop among the graph's own nodes, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(edges.get(node, set()) & edges.keys()):
            if state.get(nxt) == 1:
                return [*stack[stack.index(nxt):], nxt]
            if nxt not in state and (loop := visit(nxt)) is not None:
                return loop
        stack.pop()
        state[node] = 2
        return None

    for start in sorted(edges):
        if start not in state and (loop := visit(start)) is not None:
            return loop
    return None


def test_template_modules_import_no_loop() -> None:
    edges = graph(sorted((PACKAGE / "templates").glob("*.py")))
    assert {"graspd.templates.library", "graspd.templates.detector"} <= edges.keys()
    # the package's __init__ re-exports its modules; a module importing the package itself would be a loop
    assert find_cycle(edges) is None, find_cycle(edges)
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]


def test_templates_do_not_import_sim() -> None:
    for name, deps in graph(sorted((PACKAGE / "templates").glob("*.py"))).items():
        assert not any(d == "graspd.sim" or d.startswith("graspd.sim.") for d in deps), name


def test_outcome_store_and_database_do_not_import_templates() -> None:
    for name, deps in graph([PACKAGE / "outcomes.py", PACKAGE / "database.py"]).items():
        assert not any(d.startswith("graspd.templates") for d in deps), (name, deps)
