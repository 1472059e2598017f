"""Install sizes: a fresh virtual environment with what the Docker image installs (the client and the server with
its PostgreSQL extra, non-editable, from the package index or pip's cache), its size on disk and its largest
packages; and an estimate of the image (no Docker engine needed).  For a before/after: run it on this checkout
and on an older one (--repo).

    .venv/bin/python bench/install_size.py [--repo PATH] [--tag NAME]   ->  bench/results/install-NAME.md

The image estimate adds up what the final stage holds: the base image (--base-mib, python:3.11-slim, not measured
here), the installed Python packages (site-packages of the fresh venv), the Debian packages of the Dockerfile's
`apt-get install` line with their dependencies that debian:bookworm-slim lacks (apt-cache's Installed-Size), and
models/.  It is an estimate: Docker's layers, file-system overhead and python:3.11-slim's own extras differ.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import venv
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: What debian:bookworm-slim (under python:3.11-slim) holds besides the Essential packages: apt, and the shared
#: libraries python:3.11-slim keeps for its own build.  Their dependencies are in the image too.
BASE_PACKAGES = ("apt", "ca-certificates", "netbase", "tzdata", "libssl3", "libsqlite3-0", "libffi8", "libbz2-1.0",
                 "liblzma5", "libncursesw6", "libreadline8", "libuuid1", "zlib1g", "libexpat1", "libtirpc3",
                 "libnsl2", "libdb5.3")


def tree_mb(path: Path) -> float:
    """Size on disk (MiB) of everything under path."""
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) / 2**20


def dockerfile_apt_packages(dockerfile: Path) -> list[str]:
    """The packages of the Dockerfile's `apt-get install ... ` line (options dropped)."""
    text = dockerfile.read_text().replace("\\\n", " ")
    match = re.search(r"apt-get install ([^&\n]+)", text)
    return [w for w in match.group(1).split() if not w.startswith("-")] if match else []


def _recursive_depends(packages: list[str] | tuple[str, ...]) -> set[str]:
    """packages and everything they depend on (no recommends or suggests: the Dockerfile says
    --no-install-recommends), by apt-cache."""
    out = subprocess.run(["apt-cache", "depends", "--recurse", "--no-recommends", "--no-suggests", "--no-conflicts",
                          "--no-breaks", "--no-replaces", "--no-enhances", *packages],
                         capture_output=True, text=True, check=True).stdout
    return {line for line in out.splitlines() if line and not line.startswith((" ", "<"))}


def apt_estimate(packages: list[str]) -> tuple[float, list[str]] | None:
    """(MiB installed, package names) of packages and their dependencies that debian:bookworm-slim lacks (its
    Essential packages, BASE_PACKAGES and their dependencies); None without apt-cache."""
    if not packages:
        return 0.0, []
    if shutil.which("apt-cache") is None or shutil.which("dpkg-query") is None:
        return None
    status = subprocess.run(["dpkg-query", "-W", "-f=${Package} ${Essential}\n"], capture_output=True, text=True,
                            check=True).stdout
    essential = [line.split()[0] for line in status.splitlines() if line.endswith(" yes")]
    names = sorted(_recursive_depends(packages) - _recursive_depends([*essential, *BASE_PACKAGES]))
    show = subprocess.run(["apt-cache", "show", "--no-all-versions", *names], capture_output=True, text=True,
                          check=True).stdout
    kib = sum(int(k) for k in re.findall(r"^Installed-Size: (\d+)", show, re.M))
    return kib / 1024, names


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repo", type=Path, default=REPO, help="the checkout to install (default: this one)")
    ap.add_argument("--tag", default="server", help="results name: bench/results/install-TAG.md")
    ap.add_argument("--top", type=int, default=12, help="largest packages listed")
    ap.add_argument("--base-mib", type=float, default=125.0,
                    help="size of python:3.11-slim uncompressed (MiB; assumed, not measured here)")
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
        site_mb = tree_mb(site)
        packages = sorted(((p.name, tree_mb(p)) for p in site.iterdir() if p.is_dir() and not p.name.endswith(
            (".dist-info", ".egg-info")) and p.name != "__pycache__"), key=lambda x: -x[1])
        installed = subprocess.check_output([str(py), "-m", "pip", "list", "--format=json"], text=True)
        names = sorted(d["name"].lower() for d in json.loads(installed))
    heavy = {n: n in names for n in ("torch", "pybullet", "open3d", "graspd-lab", "ray", "dash", "plotly")}
    apt_packages = dockerfile_apt_packages(args.repo / "Dockerfile")
    apt = apt_estimate(apt_packages)
    models_mb = tree_mb(args.repo / "models") if (args.repo / "models").is_dir() else 0.0
    lines = [f"# Install size: {args.tag}\n", f"`pip install ./client '.[postgres]'` from `{args.repo}` into a fresh "
             f"venv (what the Docker image installs).\n", f"- venv: **{total:.0f} MiB**, {len(names)} distributions "
             f"(site-packages {site_mb:.0f} MiB)",
             "- heavy stacks present: " + ", ".join(f"{k} {'yes' if v else 'no'}" for k, v in heavy.items())]
    image: float | None = None
    if apt is not None:
        image = args.base_mib + site_mb + apt[0] + models_mb
        lines += [f"- Dockerfile apt packages: `{' '.join(apt_packages)}`: with their dependencies {len(apt[1])} "
                  f"Debian package(s) beyond debian:bookworm-slim, {apt[0]:.1f} MiB installed (apt-cache "
                  "Installed-Size)",
                  f"- **image estimate: {image:.0f} MiB** = python:3.11-slim {args.base_mib:.0f} MiB (assumed, not "
                  f"measured) + site-packages {site_mb:.0f} + apt {apt[0]:.1f} + models/ {models_mb:.0f}. An "
                  "estimate, not a built image (no Docker engine here): layers, file-system overhead and the pip "
                  "the base image already has are not told apart"]
    lines += ["", "| package | MiB |", "|---|---:|"]
    lines += [f"| {name} | {mb:.0f} |" for name, mb in packages[:args.top]]
    text = "\n".join(lines) + "\n"
    print(text)
    out = REPO / "bench" / "results" / f"install-{args.tag}.md"
    out.write_text(text)
    (out.with_suffix(".json")).write_text(json.dumps({
        "tag": args.tag, "repo": str(args.repo), "venv_mib": total, "site_packages_mib": site_mb,
        "distributions": names, "heavy": heavy, "packages": packages[:args.top], "apt_packages": apt_packages,
        "apt_mib": None if apt is None else apt[0], "apt_closure": None if apt is None else apt[1],
        "models_mib": models_mb, "base_mib_assumed": args.base_mib, "image_estimate_mib": image}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
