"""The service's tests run without the lab: in a child interpreter that cannot import graspd_lab (as a service-only
install), every test folder but tests/lab collects, except the modules that import the lab themselves (simulator
and mesh scenes), and tests on the shared box scene (render_box) pass.  The shared conftest and fixtures import
no lab."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import sysconfig
from pathlib import Path

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
#: The child runs with -S: site-packages is on its path but its .pth files are not read, so the editable lab is not
#: importable (as in tests/server/test_lab_absent.py); the service and the client come from the checkout.
SITE = Path(sysconfig.get_paths()["purelib"])
SERVICE_FOLDERS = sorted(p.name for p in TESTS.iterdir() if p.is_dir() and p.name not in ("lab", "__pycache__"))


def _child_pytest(*args: str) -> subprocess.CompletedProcess[str]:
    code = "import importlib.util, sys, pytest\nassert importlib.util.find_spec('graspd_lab') is None\n" \
           "raise SystemExit(pytest.main(sys.argv[1:]))\n"
    return subprocess.run([sys.executable, "-S", "-c", code, "-p", "no:cacheprovider", *args], capture_output=True,
                          text=True, timeout=600, cwd=ROOT,
                          env={"PYTHONPATH": f"{ROOT / 'service'}:{ROOT / 'client'}:{SITE}", "PATH": "/usr/bin:/bin"})


def _top_level_imports(path: Path) -> set[str]:
    """The modules path imports when it is loaded (module body, into if/try blocks; not in functions)."""
    out: set[str] = set()
    todo = list(ast.parse(path.read_text()).body)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
            out.add(node.module)
        elif isinstance(node, (ast.If, ast.Try)):
            todo += node.body + node.orelse + getattr(node, "finalbody", [])
    return out


def _needs_lab(path: Path, seen: frozenset[Path] = frozenset()) -> bool:
    """Whether loading path imports graspd_lab, itself or through a helper module of tests/ it imports."""
    for name in _top_level_imports(path):
        if name.split(".")[0] == "graspd_lab":
            return True
        helper = TESTS.joinpath(*name.split(".")).with_suffix(".py")
        if helper.exists() and helper not in seen and _needs_lab(helper, seen | {path}):
            return True
    return False


def test_shared_conftest_and_fixtures_import_no_lab() -> None:
    for name in ("conftest.py", "fixtures.py", "box_scene.py"):
        assert not _needs_lab(TESTS / name), name
    assert _needs_lab(TESTS / "target_scene.py")  # the check sees an import of the lab


def test_service_tests_collect_without_the_lab_but_for_modules_that_import_it() -> None:
    run = _child_pytest("--collect-only", "--continue-on-collection-errors", *[f"tests/{f}" for f in SERVICE_FOLDERS])
    failed = set(re.findall(r"ERROR collecting (tests/\S+\.py)", run.stdout))
    expected = {str(p.relative_to(ROOT)) for f in SERVICE_FOLDERS for p in (TESTS / f).rglob("test_*.py")
                if _needs_lab(p)}
    assert failed == expected, (failed ^ expected, run.stdout[-3000:])
    collected = {line.split("::")[0] for line in run.stdout.splitlines() if "::" in line}
    assert len(collected) >= 80 and not failed & collected, run.stdout[-3000:]
    assert int(re.findall(r"(\d+)(?:/\d+)? tests collected", run.stdout)[-1]) >= 700, run.stdout[-3000:]


def test_tests_on_the_shared_box_scene_pass_without_the_lab() -> None:
    run = _child_pytest("tests/gpd/test_sensor_artefacts.py", "tests/templates/test_library_store.py")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert re.search(r"\b\d+ passed", run.stdout), run.stdout[-1000:]
