"""The graspd import graph, read from the source with ast: no loops among its modules' top-level imports
(the whole tree, and the template package counting every import), no import of graspd_lab.sim by the templates,
the outcome store and database below the templates, and training reading outcomes without graspd.templates."""

from __future__ import annotations

import ast
from pathlib import Path

import graspd
import graspd_lab

PACKAGE = Path(graspd.__file__).parent
LAB = Path(graspd_lab.__file__).parent


def module_name(path: Path) -> str:
    """graspd.x.y (or graspd_lab.x.y) of a source file under the graspd or graspd_lab package."""
    root = LAB.parent if path.is_relative_to(LAB) else PACKAGE.parent
    parts = path.relative_to(root).with_suffix("").parts
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
    names; `from p import n` counts as p and, when p.n is a module, p.n (only p.n when every name it imports
    is a module of p: p itself is then run only as their package)."""
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out: set[str] = set()
    found: list[tuple[str, list[str]]] = []
    tree = ast.parse(path.read_text())
    for node in (_top_level(tree) if top_level_only else ast.walk(tree)):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*anchor, base] if base else anchor)
            found.append((base, [f"{base}.{a.name}" for a in node.names]))
    out.update(m for base, subs in found for m in (subs if all(s in KNOWN for s in subs) else [base, *subs]))
    return {m for m in out if m in KNOWN and m != name}


KNOWN = {module_name(p) for p in [*PACKAGE.rglob("*.py"), *LAB.rglob("*.py")]}


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
    edges = graph(sorted((PACKAGE / "templates").glob("*.py")))
    assert len(edges) >= 6
    for name, deps in edges.items():
        assert not any(d == "graspd_lab.sim" or d.startswith("graspd_lab.sim.") for d in deps), name


def test_outcome_store_and_database_do_not_import_templates() -> None:
    edges = graph([PACKAGE / "store" / "outcomes.py", PACKAGE / "store" / "database.py"])
    assert edges["graspd.store.outcomes"] == {"graspd.store.database", "graspd.core.types"}  # the graph is read
    for name, deps in edges.items():
        assert not any(d.startswith("graspd.templates") for d in deps), (name, deps)


def test_graspd_modules_import_no_loop_counting_function_level_imports() -> None:
    """No cycle among every import of every graspd module, those inside functions included (a lazy import hides
    a loop from the import system, not from a reader)."""
    edges = graph(sorted(PACKAGE.rglob("*.py")))
    assert {"graspd.server.app", "graspd.gpd.detector", "graspd.io.inputs"} <= edges.keys()
    assert find_cycle(edges) is None, find_cycle(edges)


def test_graspd_modules_import_no_loop_at_top_level() -> None:
    """No cycle among the imports every graspd module runs when it is imported (the lazy ones, inside
    functions, load the heavy optional stacks and are not counted)."""
    edges = graph(sorted(PACKAGE.rglob("*.py")), top_level_only=True)
    assert {"graspd.server.app", "graspd.gpd.detector", "graspd.store.outcomes"} <= edges.keys()
    assert find_cycle(edges) is None, find_cycle(edges)


def test_training_reads_outcomes_without_templates() -> None:
    edges = graph(sorted((LAB / "training").glob("*.py")))
    assert "graspd.store.outcomes" in edges["graspd_lab.training.rows"]  # training does read outcomes
    for name, deps in edges.items():
        assert not any(d == "graspd.templates" or d.startswith("graspd.templates.") for d in deps), (name, deps)


#: service/graspd's layers, lowest first: a module may import its own layer and those below it.
LAYERS = ("core", "io", "gpd", "store", "templates", "viz", "server", "cli")
#: graspd.server's own order, lowest first: what every transport shares, the services, the transports, the app
#: and the serve command.  A module not named is in the first (shared) rank.
SERVER_RANKS = (("graspd.server.services",), ("graspd.server.api", "graspd.server.zenoh", "graspd.server.ros2"),
                ("graspd.server.app",), ("graspd.server.runner", "graspd.server.cli", "graspd.server.openapi"))
#: The lab modules graspd may import (lazily, in a function), and why.
LAB_IMPORTS_ALLOWED = {
    "graspd.cli.main": "`graspd demo` renders its scene with the lab's world (a clear error without it)"}


def rank(module: str) -> tuple[int, int]:
    """(layer, rank within the server) of a graspd module; the package graspd itself is lowest."""
    parts = module.split(".")
    layer = LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else -1
    sub = 0
    for i, prefixes in enumerate(SERVER_RANKS, start=1):
        if any(module == p or module.startswith(p + ".") for p in prefixes):
            sub = i
    return layer, sub


def transport(module: str) -> str | None:
    """The server transport (api, zenoh, ros2) a module belongs to, or None."""
    for prefix in SERVER_RANKS[1]:
        if module == prefix or module.startswith(prefix + "."):
            return prefix
    return None


def upward(edges: dict[str, set[str]]) -> list[tuple[str, str]]:
    """The imports that go from a lower layer (or server rank) to a higher one, or from one transport to
    another (what two transports share belongs in services/)."""
    def wrong(a: str, b: str) -> bool:
        across = transport(a) is not None and transport(b) not in (None, transport(a))
        return b.startswith("graspd.") and (rank(b) > rank(a) or across)

    return sorted((a, b) for a, deps in edges.items() for b in deps if wrong(a, b))


def test_layers_import_only_downward() -> None:
    """Every import in service/graspd, lazy ones in functions included, goes to the module's own layer or below."""
    edges = graph(sorted(PACKAGE.rglob("*.py")))
    assert {"graspd.core.cloud", "graspd.gpd.detector", "graspd.server.app", "graspd.cli.main"} <= edges.keys()
    assert upward(edges) == []
    # the rule sees a violation: the core importing the detector, an engine importing a router
    assert upward({"graspd.core.cloud": {"graspd.gpd.detector"}}) == [("graspd.core.cloud", "graspd.gpd.detector")]
    assert upward({"graspd.server.services.engine": {"graspd.server.api.detect"}}) != []
    assert upward({"graspd.server.ros2.node": {"graspd.server.zenoh.node"}}) != []


def test_top_level_of_graspd_holds_at_most_eight_modules() -> None:
    entries = [p.name for p in PACKAGE.iterdir()
               if (p.is_dir() and (p / "__init__.py").exists()) or (p.suffix == ".py" and p.stem != "__init__")]
    assert set(LAYERS) <= {e.removesuffix(".py") for e in entries}
    assert len(entries) <= 8, sorted(entries)


def _imports_named(path: Path, prefix: str) -> set[str]:
    """The modules of import statements in path whose name starts with prefix (anywhere in the file)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == prefix)
        elif isinstance(node, ast.ImportFrom) and not node.level and (node.module or "").split(".")[0] == prefix:
            out.add(node.module or "")
    return out


def test_only_the_server_and_io_import_the_wire_package() -> None:
    """The core, the algorithm, the store, the templates and the pictures own their values and errors; only the
    transport edge (server/, io/) imports graspd_client."""
    users = {module_name(p) for p in PACKAGE.rglob("*.py") if _imports_named(p, "graspd_client")}
    assert "graspd.server.wire.detect" in users
    assert sorted(u for u in users if rank(u)[0] not in (LAYERS.index("io"), LAYERS.index("server"))) == []


def test_the_wire_package_imports_nothing_above_the_core() -> None:
    """graspd.server.wire (the models of what the transports send and receive) imports graspd.core and itself
    only: the detector's, the templates' and the readers' types stay out of the wire contract (the mapping to them
    is graspd.server.services.mapping)."""
    wire = sorted((PACKAGE / "server" / "wire").glob("*.py"))
    edges = graph(wire)
    assert {"graspd.server.wire.detect", "graspd.server.wire.response", "graspd.server.wire.errors"} <= edges.keys()
    above = {name: sorted(d for d in deps if not d.startswith(("graspd.core", "graspd.server.wire")))
             for name, deps in edges.items()}
    assert {name: deps for name, deps in above.items() if deps} == {}
    assert imports_of(PACKAGE / "server" / "services" / "mapping.py") >= {"graspd.server.wire.detect",
                                                                         "graspd.gpd.detector"}  # the rule sees


def test_graspd_does_not_import_the_lab() -> None:
    users = {module_name(p) for p in PACKAGE.rglob("*.py") if _imports_named(p, "graspd_lab")}
    assert users <= LAB_IMPORTS_ALLOWED.keys(), users - LAB_IMPORTS_ALLOWED.keys()
    lab_users = {module_name(p) for p in LAB.rglob("*.py") if _imports_named(p, "graspd")}
    assert "graspd_lab.training.scene_data" in lab_users  # the lab builds on graspd
