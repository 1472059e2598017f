"""Install sizes: a fresh virtual environment with what the Docker image installs (the client and the server with
its PostgreSQL extra, non-editable, from the package index or pip's cache), its size on disk and its largest
packages.  Issue 25's before/after: run it on this checkout and on an older one (--repo).

    .venv/bin/python bench/install_size.py [--repo PATH] [--tag NAME]   ->  bench/results/install-NAME.md
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def tree_mb(path: Path) -> float:
    """Size on disk (MiB) of everything under path."""
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) / 2**20


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repo", type=Path, default=REPO, help="the checkout to install (default: this one)")
    ap.add_argument("--tag", default="server", help="results name: bench/results/install-TAG.md")
    ap.add_argument("--top", type=int, default=12, help="largest packages listed")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        env = Path(tmp) / "venv"
        venv.EnvBuilder(with_pip=True).create(env)
        py = env / "bin" / "python"
        subprocess.run([str(py), "-m", "pip", "install", "-q", str(args.repo / "client"), f"{args.repo}[postgres]"],
                       check=True)
        purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
        site = Path(subprocess.check_output([str(py), "-c", purelib], text=True).strip())
        total = tree_mb(env)
        packages = sorted(((p.name, tree_mb(p)) for p in site.iterdir() if p.is_dir() and not p.name.endswith(
            (".dist-info", ".egg-info")) and p.name != "__pycache__"), key=lambda x: -x[1])
        installed = subprocess.check_output([str(py), "-m", "pip", "list", "--format=json"], text=True)
        names = sorted(d["name"].lower() for d in json.loads(installed))
    heavy = {n: n in names for n in ("torch", "pybullet", "open3d", "graspd-lab", "ray")}
    lines = [f"# Install size: {args.tag}\n", f"`pip install ./client '.[postgres]'` from `{args.repo}` into a fresh "
             f"venv (what the Docker image installs).\n", f"- venv: **{total:.0f} MiB**, {len(names)} distributions",
             "- heavy stacks present: " + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in heavy.items()), "",
             "| package | MiB |", "|---|---:|"]
    lines += [f"| {name} | {mb:.0f} |" for name, mb in packages[:args.top]]
    text = "\n".join(lines) + "\n"
    print(text)
    out = REPO / "bench" / "results" / f"install-{args.tag}.md"
    out.write_text(text)
    (out.with_suffix(".json")).write_text(json.dumps({"tag": args.tag, "repo": str(args.repo), "venv_mib": total,
                                                      "distributions": names, "heavy": heavy,
                                                      "packages": packages[:args.top]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
