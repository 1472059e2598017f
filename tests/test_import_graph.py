"""The graspd import graph, read from the source with ast: no loops among its modules' top-level imports
(the whole tree, and the template package counting every import), no import of graspd_lab.sim by the templates,
the outcome store and database below the templates, and training reading outcomes without graspd.templates."""

from __future__ import annotations

import ast
from pathlib import Path

import graspd

PACKAGE = Path(graspd.__file__).parent


def module_name(path: Path) -> str:
    """graspd.x.y of a source file under the graspd package."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _top_level(tree: ast.Module) -> list[ast.stmt]:
    """The statements run when the module is imported: its body, into if/try/with blocks, not into functions
    or classes' methods, nor `if TYPE_CHECKING:`."""
    out: list[ast.stmt] = []
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        out.append(node)
        if isinstance(node, ast.If) and not (isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING"):
            todo += node.body + node.orelse
        elif isinstance(node, ast.Try):
            todo += node.body + node.orelse + node.finalbody + [s for h in node.handlers for s in h.body]
        elif isinstance(node, (ast.With, ast.ClassDef)):
            todo += node.body
    return out


def imports_of(path: Path, top_level_only: bool = False) -> set[str]:
    """Every graspd module path imports (anywhere in the file, or only where it runs on import), as absolute
    names; `from p import n` counts as p and, when p.n is a module, p.n."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    tree = ast.parse(path.read_text())
    for node in (_top_level(tree) if top_level_only else ast.walk(tree)):
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


def graph(modules: list[Path], top_level_only: bool = False) -> dict[str, set[str]]:
    return {module_name(p): imports_of(p, top_level_only) for p in modules}


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
        assert not any(d == "graspd_lab.sim" or d.startswith("graspd_lab.sim.") for d in deps), name


def test_outcome_store_and_database_do_not_import_templates() -> None:
    for name, deps in graph([PACKAGE / "outcomes.py", PACKAGE / "database.py"]).items():
        assert not any(d.startswith("graspd.templates") for d in deps), (name, deps)


def test_graspd_modules_import_no_loop_at_top_level() -> None:
    """No cycle among the imports every graspd module runs when it is imported (the lazy ones, inside
    functions, load the heavy optional stacks and are not counted)."""
    edges = graph(sorted(PACKAGE.rglob("*.py")), top_level_only=True)
    assert {"graspd.server.app", "graspd.gpd.detector", "graspd_lab.world.scenes", "graspd.store.outcomes"} <= edges.keys()
    assert find_cycle(edges) is None, find_cycle(edges)


def test_training_reads_outcomes_without_templates() -> None:
    for name, deps in graph(sorted((PACKAGE / "training").glob("*.py"))).items():
        assert not any(d == "graspd.templates" or d.startswith("graspd.templates.") for d in deps), (name, deps)
