"""The documentation: the README's two commands are the ones CI and the Makefile run, every GRASPD_* variable the
pages name is one the code reads, the pages made at build time (docs/hooks) cover every setting, the whole OpenAPI
spec and every benchmark results file, the repository files the pages name exist, and no page names a tracker
item.  The site itself is built by `make docs` (mkdocs build --strict), which `make test` runs first."""

from __future__ import annotations

import json
import re
from pathlib import Path
from types import ModuleType

from graspd.server.settings import Settings
from repo_module import load_module

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.rglob("*.md"))
TRACKER = re.compile(r"\b[Ii]ssues? \d+|\bDESIGN\.md\b")
VARIABLE = re.compile(r"\bGRASPD_[A-Z0-9_]*[A-Z0-9]\b")


def hook(name: str) -> ModuleType:
    """A hook of mkdocs.yml, loaded from docs/hooks/ as MkDocs loads it."""
    return load_module(DOCS / "hooks" / f"{name}.py", f"docs_hook_{name}")


def text_of_pages() -> str:
    return "\n".join(p.read_text(encoding="utf-8") for p in [*PAGES, ROOT / "README.md"])


def test_readme_quick_start_is_the_two_commands_that_ci_and_the_makefile_run() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"## Quick start[^\n]*\n+```bash\n(.*?)```", readme, re.DOTALL)
    assert block, "README.md has no Quick start section with a bash block"
    commands = [line.split("#", 1)[0].strip() for line in block.group(1).splitlines() if line.strip()]
    assert commands == ["make demo", "make test"]
    ci = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()
          if line.strip() and not line.startswith("#") and not line.startswith(("set ", "cd "))]
    assert ci[-1] == commands[1], ".ci/run must run the README's test command"
    makefile = (ROOT / "Makefile").read_text()
    test_target = re.search(r"^test:(.*)$", makefile, re.MULTILINE)
    assert test_target and "docs" in test_target.group(1).split()
    docs_recipe = re.search(r"^docs:.*\n\t(.*)$", makefile, re.MULTILINE)
    assert docs_recipe and "mkdocs build --strict" in docs_recipe.group(1)


def test_every_graspd_variable_the_pages_name_is_read_by_the_code() -> None:
    prefix = Settings.model_config.get("env_prefix", "")
    settings = {f"{prefix}{name.upper()}" for name in Settings.model_fields}
    named = set(VARIABLE.findall(text_of_pages()))
    code = "\n".join(p.read_text(encoding="utf-8", errors="replace")
                     for folder in ("service/graspd", "lab/graspd_lab", "examples")
                     for p in (ROOT / folder).rglob("*") if p.is_file() and p.suffix in (".py", ".yaml", ".cfg"))
    unknown = sorted(v for v in named - settings if not re.search(rf"\b{v}\b", code))
    assert not unknown, f"the docs name variables nothing reads: {unknown}"


def test_the_settings_table_lists_every_setting_with_its_description() -> None:
    module = hook("settings_table")
    table = module.settings_table(Settings)
    prefix = Settings.model_config.get("env_prefix", "")
    rows = {line.split("|")[1].strip().strip("`"): line for line in table.splitlines()[2:]}
    assert set(rows) == {f"{prefix}{name.upper()}" for name in Settings.model_fields}
    assert "Port" not in rows and rows[f"{prefix}PORT"].split("|")[3].strip() == "`8000`"
    assert "<" not in table.replace("`", "").replace("&lt;", "")  # no description is swallowed as an HTML tag
    page = (DOCS / "deploy" / "configuration.md").read_text(encoding="utf-8")
    assert module.MARKER in page
    config = (ROOT / "mkdocs.yml").read_text()
    for name in ("settings_table", "openapi_pages", "repo_pages"):
        assert f"docs/hooks/{name}.py" in config


def test_the_api_pages_hold_every_route_and_model_of_the_spec_and_their_links_resolve() -> None:
    module = hook("openapi_pages")
    spec = json.loads((ROOT / "openapi" / "openapi.json").read_text())
    http, models = module.http_page(spec), module.models_page(spec)
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            assert f"## {method.upper()} {path} {{#{op['operationId']}}}" in http
    headings = set(re.findall(r"^## (\w+)$", models, re.MULTILINE))
    assert headings == set(spec["components"]["schemas"])
    anchors = {name.lower() for name in headings}
    targets = set(re.findall(r"\]\(models\.md#(\w+)\)", http)) | set(re.findall(r"\]\(#(\w+)\)", models))
    assert targets and targets <= anchors
    assert module.type_of({"anyOf": [{"$ref": "#/components/schemas/Hand"}, {"type": "null"}]}) == \
        "[Hand](#hand) or null"
    assert module.cell('read as {"mode": string} | `a<b>`') == 'read as &#123;"mode": string} \\| `a<b>`'


def test_every_results_file_has_a_page_and_each_picture_goes_to_its_own_file() -> None:
    module = hook("repo_pages")
    results = ROOT / "bench" / "results"
    pictures = sorted(p for p in results.rglob("*") if p.suffix in module.PICTURES)
    assert pictures
    assert module.owner(results / "load_latency.png") == results / "load.md"
    assert module.owner(results / "clutter-gpd-vgn-scenes.png") == results / "clutter-gpd-vgn.md"
    assert module.owner(results / "clutter-pile-centred.png") == results / "clutter-pile-centred.md"
    pages = [(f"benchmarks/results/{p.name}", p) for p in sorted(results.glob("*.md"))]
    index = module.results_index(pages, pictures)
    for _, path in pages:
        assert f"]({path.name})" in index
    for path in pictures:
        assert f"]({path.relative_to(results).as_posix()})" in index


def test_the_repository_files_the_pages_name_exist() -> None:
    named = set(re.findall(r"`((?:bench|examples|tests|scripts|models|openapi|client|lab)/[\w./-]+\.\w+)`",
                           text_of_pages()))
    assert named
    placeholder = re.compile(r"\*|(^|/)\.?[A-Z]+(/|\.)|/\.work/")  # models/NAME.pt, models/.work/NAME/last.pt
    missing = sorted(n for n in named if not placeholder.search(n) and not (ROOT / n).exists())
    assert not missing, f"the docs name files the repository does not hold: {missing}"


def test_no_page_names_a_tracker_item() -> None:
    files = [*PAGES, *sorted((DOCS / "hooks").glob("*.py")), ROOT / "README.md", ROOT / "mkdocs.yml"]
    found = [f"{p.relative_to(ROOT)}:{n}: {line.strip()}" for p in files
             for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if TRACKER.search(line)]
    assert not found, "\n".join(found)
