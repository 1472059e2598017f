"""MkDocs hook: pages and pictures the repository already holds, put into the site at build time (never copied into
docs/, so there is one copy of each figure).

- ``bench/results/*.md`` and every picture in ``bench/results/`` become ``benchmarks/results/...``, with an index
  page ``benchmarks/results/index.md`` listing them;
- ``models/README.md`` becomes ``models/shipped.md``; ``models/evaluation/**`` (tables and PR curves written by
  ``bench/classifier.py``) becomes ``models/evaluation/...``;
- ``examples/robot/*.png`` (drawn by ``examples/robot/pictures.py``) become ``assets/robot/...``.

The Markdown files are included as they were written; each generated page starts with a line naming its source.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
PICTURES = (".png", ".svg", ".jpg")
HEADING = re.compile(r"^#\s+(.+?)\s*$", re.MULTILINE)


def title_of(text: str, fallback: str) -> str:
    """The file's first level-1 heading, else the fallback."""
    match = HEADING.search(text)
    return match.group(1) if match else fallback


def source_note(path: Path) -> str:
    """A line saying which committed file a generated page shows."""
    return f"*This page is `{path.relative_to(ROOT).as_posix()}` from the repository, as committed.*\n\n"


def owner(picture: Path) -> Path | None:
    """The results file a picture was written beside under its name (load_latency.png for load.md,
    clutter-gpd-vgn-scenes.png for clutter-gpd-vgn.md): the longest Markdown stem it starts with."""
    stems = [md.stem for md in picture.parent.glob("*.md")
             if picture.stem == md.stem or picture.stem.startswith((md.stem + "-", md.stem + "_"))]
    return picture.parent / f"{max(stems, key=len)}.md" if stems else None


def own_pictures(path: Path, text: str) -> str:
    """The pictures of a results file that it does not show itself, drawn at the end of its page."""
    names = [p.name for p in sorted(path.parent.iterdir())
             if p.suffix in PICTURES and owner(p) == path and f"]({p.name})" not in text]
    return "".join(f"\n![{name}]({name})\n" for name in names)


def add_tree(files: Files, config: Any, source: Path, target: str) -> list[tuple[str, Path]]:
    """Adds every Markdown file and picture under source as target/...; returns (uri, path) of the Markdown."""
    pages = []
    for path in sorted(source.rglob("*")):
        if not path.is_file():
            continue
        uri = f"{target}/{path.relative_to(source).as_posix()}"
        if path.suffix == ".md":
            text = path.read_text(encoding="utf-8")
            files.append(File.generated(config, uri, content=source_note(path) + text + own_pictures(path, text)))
            pages.append((uri, path))
        elif path.suffix in PICTURES:
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    return pages


def results_index(pages: list[tuple[str, Path]], pictures: list[Path]) -> str:
    """The page listing every results file and picture of bench/results/."""
    lines = ["# All results files", "",
             "Every table and picture the benchmarks in `bench/` wrote into `bench/results/`, as committed. The",
             "[benchmarks page](../index.md) says which command made which file and quotes the headline figures.",
             "", "| file | title |", "|---|---|"]
    for uri, path in pages:
        name = uri.rsplit("/", 1)[-1]
        title = title_of(path.read_text(encoding="utf-8"), path.stem).replace("|", "\\|")
        lines.append(f"| [{name}]({name}) | {title} |")
    lines += ["", "## Pictures", "",
              "A picture written under a results file's name is also drawn at the end of that file's page.", ""]
    for path in pictures:
        rel = path.relative_to(ROOT / "bench" / "results").as_posix()
        lines.append(f"- [{rel}]({rel})")
    return "\n".join(lines) + "\n"


def on_files(files: Files, config: Any, **_: Any) -> Files:
    results = ROOT / "bench" / "results"
    pages = add_tree(files, config, results, "benchmarks/results")
    pictures = sorted(p for p in results.rglob("*") if p.suffix in PICTURES)
    files.append(File.generated(config, "benchmarks/results/index.md", content=results_index(pages, pictures)))
    add_tree(files, config, ROOT / "models" / "evaluation", "models/evaluation")
    readme = ROOT / "models" / "README.md"
    files.append(File.generated(config, "models/shipped.md",
                                content=source_note(readme) + readme.read_text(encoding="utf-8")))
    for path in sorted((ROOT / "examples" / "robot").glob("*.png")):
        files.append(File.generated(config, f"assets/robot/{path.name}", abs_src_path=str(path)))
    return files
