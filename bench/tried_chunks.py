"""Collect the oracle's tried grasps in chunks of rounds: a long, stoppable and resumable bench/oracle.py job.

Each chunk is one bench/oracle.py run (--perturb 4 --images) over a range of round seeds, written to DIR as
oracle-<objects>-<kind>-s<first seed>.json and tried-<objects>-<kind>-s<first seed>.npz (objects: a training set,
household-training with the benchmark's hand or scaled-training with graspd's default hand).  A chunk
whose JSON exists is done and skipped, so the job is stopped with a kill and resumed by running the same command
again (a killed chunk starts over).  Several kinds (scenes or container styles) are collected in turn, one chunk
of each, so a stopped job holds some of every kind.  Training objects only: bench/reranker.py --dir DIR fits on them.

  nohup env PYTHONPATH=service:client:lab .venv/bin/python bench/tried_chunks.py --kinds pile-side tray \\
      --first-seed 300 --chunks 10 --dir data/generated/tried > data/generated/tried.log 2>&1 &
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import clutter  # noqa: E402
from containers import STYLES  # noqa: E402
from foresight import TRAINING_OBJECT_SETS as TRAINING_SETS  # noqa: E402

#: Lifts per tried grasp: its own and 4 perturbed copies (bench/reranker.py's target is the share that held).
PERTURB = 4
TOP = 5


def chunk_name(kind: str, first: int, objects: str = TRAINING_SETS[0]) -> str:
    """A chunk's tag: its objects (a training set), kind and first seed."""
    return f"{objects}-{kind}-s{first}"


def chunk_command(kind: str, first: int, size: int, folder: Path, model: str | None,
                  objects: str = TRAINING_SETS[0]) -> list[str]:
    """The bench/oracle.py command line of one chunk: kind's scenes, seeds first .. first + size - 1."""
    place = ["--container", kind, "--split", "training"] if kind in STYLES else ["--scene", kind]
    name = chunk_name(kind, first, objects)
    cmd = [sys.executable, str(REPO / "bench" / "oracle.py"), *place, "--object-set", objects,
           "--seed", str(first), "--rounds", str(size), "--top", str(TOP), "--perturb", str(PERTURB),
           "--images", str(folder / f"tried-{name}.npz"), "--out", str(folder), "--tag", name]
    return cmd + (["--model", model] if model else [])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", nargs="+", required=True, choices=[*clutter.SCENES, *STYLES],
                    help="scene kinds or container styles, collected one chunk of each in turn")
    ap.add_argument("--first-seed", type=int, default=300)
    ap.add_argument("--chunks", type=int, default=10, help="chunks of each kind")
    ap.add_argument("--size", type=int, default=10, help="rounds per chunk")
    ap.add_argument("--dir", type=Path, default=REPO / "data" / "generated" / "tried")
    ap.add_argument("--object-set", choices=TRAINING_SETS, default=TRAINING_SETS[0],
                    help="the training objects (household at true size with the benchmark's hand, or scaled ones "
                    "with graspd's default hand)")
    ap.add_argument("--model", default=None, help="the model whose top grasps are tried (default: the service's)")
    args = ap.parse_args(argv)
    args.dir.mkdir(parents=True, exist_ok=True)
    for c in range(args.chunks):
        first = args.first_seed + c * args.size
        for kind in args.kinds:
            name = chunk_name(kind, first, args.object_set)
            if (args.dir / f"oracle-{name}.json").exists():
                print(f"{kind} seeds {first}-{first + args.size - 1}: done", flush=True)
                continue
            print(f"{kind} seeds {first}-{first + args.size - 1}: collecting", flush=True)
            done = subprocess.run(chunk_command(kind, first, args.size, args.dir, args.model,
                                                args.object_set), cwd=REPO,
                                  stdout=subprocess.DEVNULL, check=False)
            if done.returncode != 0:
                print(f"{kind} seeds {first}: bench/oracle.py exited {done.returncode}", flush=True)
                return done.returncode
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
