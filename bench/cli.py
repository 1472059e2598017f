"""Start-up time of the graspd command line: `graspd --help`, `graspd --version` and, for scale, a bare Python
and `graspd detect --help` (which imports nothing more either).  Each command runs N times in a fresh process;
the table gives the median, the fastest and the slowest wall time (s).  The target: `graspd --help` answers in
at most 1 s on 2 cores.  With --detect CLOUD it also times a whole `graspd detect CLOUD` (reading the file,
loading the models, the detection with the CLI's defaults, writing the JSON), whose target is at most
1.5 s for table_mug.pcd.

    python bench/cli.py [--runs 15] [--graspd .venv/bin/graspd] [--detect ../shared/data/real/table_mug.pcd]
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: The target for `graspd --help` (s, median).
HELP_BUDGET_S = 1.0
#: The target for a whole `graspd detect table_mug.pcd` (s, median).
DETECT_BUDGET_S = 1.5


def wall_times(command: list[str], runs: int) -> list[float]:
    """Wall-clock seconds of `runs` fresh runs of command (output discarded); RuntimeError if one fails."""
    out: list[float] = []
    for _ in range(runs):
        t = time.perf_counter()
        proc = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=False)
        out.append(time.perf_counter() - t)
        if proc.returncode != 0:
            raise RuntimeError(f"{' '.join(command)} exited {proc.returncode}: {proc.stderr.decode()[-500:]}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=15, help="fresh processes per command (default 15)")
    parser.add_argument("--graspd", help="the graspd executable (default: the one beside this Python, else PATH)")
    parser.add_argument("--detect", metavar="CLOUD", help="also time `graspd detect CLOUD --out FILE` whole")
    args = parser.parse_args(argv)
    exe = args.graspd or str(Path(sys.executable).with_name("graspd"))
    if not Path(exe).is_file():
        exe = shutil.which("graspd") or ""
    if not exe:
        print("bench/cli.py: no graspd executable found; pass --graspd PATH (make setup installs one)",
              file=sys.stderr)
        return 2
    commands = {
        "python -c pass (interpreter alone)": [sys.executable, "-c", "pass"],
        "graspd --help": [exe, "--help"],
        "graspd --version": [exe, "--version"],
        "graspd detect --help": [exe, "detect", "--help"],
    }
    if args.detect:
        out = Path(tempfile.gettempdir()) / f"graspd-bench-cli-{os.getpid()}.json"
        commands[f"graspd detect {Path(args.detect).name}"] = [exe, "detect", args.detect, "--out", str(out)]
    print(f"{args.runs} fresh runs each, {os.cpu_count()} cores visible ({len(os.sched_getaffinity(0))} usable)\n")
    print("| command | median (s) | min (s) | max (s) |")
    print("|---|---:|---:|---:|")
    medians: dict[str, float] = {}
    for name, command in commands.items():
        times = wall_times(command, args.runs)
        medians[name] = statistics.median(times)
        print(f"| `{name}` | {medians[name]:.3f} | {min(times):.3f} | {max(times):.3f} |")
    verdict = "within" if medians["graspd --help"] <= HELP_BUDGET_S else "OVER"
    print(f"\n`graspd --help` median {medians['graspd --help']:.3f} s: {verdict} the {HELP_BUDGET_S:g} s budget")
    ok = verdict == "within"
    if args.detect:
        name = f"graspd detect {Path(args.detect).name}"
        within = medians[name] <= DETECT_BUDGET_S
        print(f"`{name}` median {medians[name]:.3f} s: {'within' if within else 'OVER'} the {DETECT_BUDGET_S:g} s "
              f"budget (load average {' '.join(f'{x:.2f}' for x in os.getloadavg())})")
        ok = ok and within
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
