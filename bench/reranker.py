"""Can the classifier learn which of its top grasps hold?  A cross-validated fine-tune on the oracle's tried grasps.

bench/oracle.py --perturb N --images FILE keeps, for every detection, the images of the service's top feasible
grasps as the service encoded them, whether each held when lifted in physics, and the share of its N perturbed
copies (2 mm, 3 degrees) that held.  Here the default model is fine-tuned on those images, the target being the
share of all 1 + N lifts of a grasp that held, and asked to choose among each detection's tried grasps: the one
with the highest fine-tuned score times the detection's other ranking terms (utility, width, unknown: the key
divided by the old score).  Folds are by round seed (a round's detections are never in training and test at once)
or, with --folds-by object, by the object each tried grasp went for: a grasp's fine-tuned score then comes from a
model that never saw that object, which is what held-out objects ask of it.

The table compares, per detection, the grasp the service ranks first, the old score's choice, the fine-tuned one
and the most robust tried grasp (what no detector can know): how often the choice's own lift held and the mean
share of its perturbed copies that held.  Training-object records only (bench/oracle.py --object-set
household-training): the held-out objects are never trained or tuned on.

  PYTHONPATH=service:client:lab .venv/bin/python bench/reranker.py \\
      --images data/generated/tried-pile.npz data/generated/tried-packed.npz \\
      --records bench/results/oracle-household-training-pile-images.json \\
                bench/results/oracle-household-training-packed-images.json --tag household-training
writes bench/results/reranker-<tag>.md and .json.  --dir DIR adds every chunk bench/tried_chunks.py wrote there.
--export NAME then fine-tunes on every record and writes models/NAME.onnx, .pt and its card (the cross-validated
table in its metrics): an ablation model a request names.  --mix A makes both, the folds' scores and the export,
from A x the fine-tuned weights + (1 - A) x the starting model's.  --replay DIR adds to every epoch as many rows of a
scene_data grasp-image dataset (analytic labels, candidates of every rank) as there are tried grasps.  --seeds K
averages K fine-tunes of different seeds weight for weight (a model soup) in each fold and in the export.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
for sub in ("service", "client", "lab", "bench"):
    if str(REPO / sub) not in sys.path:
        sys.path.insert(0, str(REPO / sub))

import numpy as np  # noqa: E402
import torch  # noqa: E402
from numpy.typing import NDArray  # noqa: E402
from torch import nn  # noqa: E402

import clutter  # noqa: E402
from foresight import training_objects  # noqa: E402
from graspd_lab.training.dataset import iter_chunks  # noqa: E402
from graspd_lab.training.export import (  # noqa: E402
    PARITY_TOLERANCE,
    check_parity,
    export_onnx,
    save_weights,
    torch_scores,
    write_card,
)
from graspd_lab.training.loop import load_weights, resolve_weights  # noqa: E402
from oracle import other_terms  # noqa: E402

#: Fine-tuning: batch norm statistics frozen (the images are the model's own kind).  Epochs and learning rate picked
#: on the packed records' folds alone (6-30 epochs, 1e-4 to 1e-3 all picked better than the first grasp).
EPOCHS = 15
LEARNING_RATE = 3e-4
BATCH = 64
#: Share of the fine-tuned weights in the exported network, the rest the starting model's (1: the fine-tune alone).
#: Weight-space averaging keeps what the starting model knew about grasps the tried records never show (those
#: outside every detection's top 5) while taking the fine-tune's ordering of the top ones.
MIX = 1.0


def chunk_files(folder: Path) -> tuple[list[Path], list[Path]]:
    """The (images, records) pairs bench/tried_chunks.py wrote in folder: finished chunks only (their JSON exists)."""
    records = sorted(folder.glob("oracle-*.json"))
    images = [r.with_name("tried-" + r.name.removeprefix("oracle-")).with_suffix(".npz") for r in records]
    missing = [str(i) for i in images if not i.exists()]
    if missing:
        raise SystemExit(f"{folder}: records without their images: {', '.join(missing)}")
    return images, records


def scene_kind(scenes: str) -> str:
    """The scene kind or container style of a run's meta["scenes"] ("tray (training ranges), ..." -> "tray")."""
    return scenes.split(",")[0].split(" (")[0].strip()


def load_tried(images: list[Path], records: list[Path]) -> dict[str, NDArray[Any]]:
    """The tried grasps of every run, concatenated: images, target (share of all lifts that held), held, robust,
    seed, detection (unique across runs), rank, score, terms (key / score: the other ranking terms), object (the
    object-set id the hand went for; -1: none near, or a run older than the column) and kind (scene kind)."""
    parts: list[dict[str, NDArray[Any]]] = []
    offset = 0
    for img_path, rec_path in zip(images, records, strict=True):
        data = dict(np.load(img_path))
        rec = json.loads(rec_path.read_text())
        if not training_objects(rec["meta"]):
            raise SystemExit(f"{rec_path}: records of {rec['meta']['scenes']!r}: only training objects are fitted on")
        perturb = int(rec["meta"]["perturb"])
        if perturb < 1:
            raise SystemExit(f"{rec_path}: made without --perturb; the target needs the perturbed lifts")
        dets = rec["detections"]
        data["terms"] = other_terms([dets[d]["trial_seen"][r].get("ranking") for d, r in
                                     zip(data["detection"], data["rank"], strict=True)], data["score"])
        data["object"] = data["object"] if "object" in data else np.full(len(data["rank"]), -1, np.int64)
        data["kind"] = np.full(len(data["rank"]), scene_kind(rec["meta"]["scenes"]))
        data["target"] = (data["held"] + perturb * data["robust"]) / (perturb + 1)
        data["detection"] = data["detection"] + offset
        offset = int(data["detection"].max()) + 1 if len(data["detection"]) else offset
        parts.append(data)
    keys = ("images", "target", "held", "robust", "seed", "detection", "rank", "score", "terms", "object", "kind")
    return {k: np.concatenate([p[k] for p in parts]) for k in keys}


def load_replay(folders: list[Path]) -> tuple[NDArray[np.uint8], NDArray[np.float64]]:
    """Every row of the grasp-image datasets in folders (graspd_lab.training.scene_data's format): images, labels."""
    chunks = [c for f in folders for c in iter_chunks(f)]
    if not chunks:
        return np.zeros((0, 15, 60, 60), np.uint8), np.zeros(0)
    return (np.concatenate([c["images"] for c in chunks]),
            np.concatenate([c["labels"] for c in chunks]).astype(np.float64))


def fine_tune(net: nn.Module, images: NDArray[np.uint8], target: NDArray[np.float64], seed: int,
              epochs: int = EPOCHS, lr: float = LEARNING_RATE,
              replay: tuple[NDArray[np.uint8], NDArray[np.float64]] | None = None) -> nn.Module:
    """net fine-tuned on images toward the soft targets (cross-entropy on the logit difference), batch norm frozen.
    replay (images, labels): each epoch adds as many of its rows, drawn afresh, as there are tried grasps, so the
    candidates the tried records never show keep the labels the model first learned them with."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=1e-4)
    loss_fn = nn.BCEWithLogitsLoss()
    x_all = torch.from_numpy(images.astype(np.float32) / 255.0)
    y_all = torch.from_numpy(target.astype(np.float32))
    extra = replay is not None and len(replay[1]) > 0
    for _ in range(epochs):
        net.train()
        for m in net.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()
        x_ep, y_ep = x_all, y_all
        if extra:
            assert replay is not None
            pick = rng.choice(len(replay[1]), size=min(len(images), len(replay[1])), replace=False)
            x_ep = torch.cat([x_all, torch.from_numpy(replay[0][pick].astype(np.float32) / 255.0)])
            y_ep = torch.cat([y_all, torch.from_numpy(replay[1][pick].astype(np.float32))])
        order = rng.permutation(len(y_ep))
        for a in range(0, len(order), BATCH):
            idx = torch.from_numpy(order[a : a + BATCH])
            logits = net(x_ep[idx])
            loss = loss_fn(logits[:, 1] - logits[:, 0], y_ep[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
    return net.eval()


def fine_tune_soup(start: Path, images: NDArray[np.uint8], target: NDArray[np.float64], seed: int, seeds: int = 1,
                   epochs: int = EPOCHS, lr: float = LEARNING_RATE,
                   replay: tuple[NDArray[np.uint8], NDArray[np.float64]] | None = None) -> nn.Module:
    """The weight average of `seeds` fine-tunes of the weights at start, from seeds seed, seed + 1000, ... (a model
    soup: batch norm is frozen, so only the learned weights differ): one run's luck of batch order and replay draw
    averaged out.  seeds 1 is fine_tune alone."""
    nets = [fine_tune(load_weights(start), images, target, seed=seed + 1000 * j, epochs=epochs, lr=lr, replay=replay)
            for j in range(seeds)]
    if len(nets) == 1:
        return nets[0]
    return weighted_average(nets, [1.0 / len(nets)] * len(nets))


def weighted_average(nets: list[nn.Module], shares: list[float]) -> nn.Module:
    """nets[-1] with every floating-point parameter and buffer set to the sum of share x that net's (same nets)."""
    states = [n.state_dict() for n in nets]
    mean = {k: sum(w * s[k] for w, s in zip(shares, states, strict=True)) if v.is_floating_point() else v
            for k, v in states[-1].items()}
    nets[-1].load_state_dict(mean)
    return nets[-1].eval()


def mix_weights(base: nn.Module, tuned: nn.Module, mix: float) -> nn.Module:
    """tuned with every floating-point parameter and buffer set to (1 - mix) x base's + mix x tuned's (same net)."""
    if mix == 1.0:
        return tuned
    return weighted_average([base, tuned], [1.0 - mix, mix])


def choices(data: dict[str, NDArray[Any]], score: NDArray[np.float64], rows: NDArray[np.int64]) -> NDArray[np.int64]:
    """For each detection among rows, the row of its tried grasp with the highest score x terms (ties: lower rank)."""
    out = []
    det = data["detection"][rows]
    for d in np.unique(det):
        mine = rows[det == d]
        mine = mine[np.argsort(data["rank"][mine], kind="stable")]
        out.append(int(mine[np.argmax(score[mine] * data["terms"][mine])]))
    return np.array(out, np.int64)


def fold_of_rows(data: dict[str, NDArray[Any]], folds: int, by: str) -> NDArray[np.int64]:
    """Each tried grasp's fold: by round seed, or by the object it went for (grasps near no object: by seed)."""
    seeds = np.unique(data["seed"])
    fold_of_seed = {int(s): i % folds for i, s in enumerate(seeds)}
    fold = np.array([fold_of_seed[int(s)] for s in data["seed"]], np.int64)
    if by == "object":
        objects = np.unique(data["object"][data["object"] >= 0])
        order = np.random.default_rng(0).permutation(len(objects))
        fold_of_object = {int(o): int(order[i]) % folds for i, o in enumerate(objects)}
        fold = np.array([fold_of_object.get(int(o), int(f)) for o, f in zip(data["object"], fold, strict=True)],
                        np.int64)
    return fold


def rule_table(data: dict[str, NDArray[Any]], base: NDArray[np.float64], tuned: NDArray[np.float64],
               rows: NDArray[np.int64]) -> dict[str, Any]:
    """Per choice rule among rows' detections: how many detections, and the share whose pick held."""
    first = rows[data["rank"][rows] == 0]
    by_rule = {"the service's first grasp": first,
               "the model's own score x the other terms (from the saved images)": choices(data, base, rows),
               "the fine-tuned score x the other terms": choices(data, tuned, rows),
               "the most robust tried grasp (oracle)": choices(data, data["target"], rows)}
    return {name: {"detections": len(picks), "held": float(data["held"][picks].mean()),
                   "robust": float(data["robust"][picks].mean()), "target": float(data["target"][picks].mean())}
            for name, picks in by_rule.items()}


def evaluate(data: dict[str, NDArray[Any]], model: str, folds: int, by: str = "seed", epochs: int = EPOCHS,
             lr: float = LEARNING_RATE, mix: float = MIX,
             replay: tuple[NDArray[np.uint8], NDArray[np.float64]] | None = None, seeds: int = 1,
             ) -> tuple[dict[str, Any], dict[str, Any], NDArray[np.float64]]:
    """Cross-validated fine-tuned scores of every tried grasp, and per choice rule the picks' hold rates: over all
    detections and per scene kind."""
    fold = fold_of_rows(data, folds, by)
    weights = resolve_weights(model)
    tuned = np.full(len(fold), np.nan)
    for k in range(folds):
        train, test = fold != k, fold == k
        if not test.any():
            continue
        net = fine_tune_soup(weights, data["images"][train], data["target"][train], seed=k, seeds=seeds,
                             epochs=epochs, lr=lr, replay=replay)
        net = mix_weights(load_weights(weights), net, mix)
        tuned[test] = torch_scores(net, data["images"][test])
    base = torch_scores(load_weights(weights), data["images"]).astype(np.float64)
    rows = np.arange(len(fold))
    kinds = {str(k): rule_table(data, base, tuned, rows[data["kind"] == k]) for k in np.unique(data["kind"])}
    return rule_table(data, base, tuned, rows), kinds, tuned


def export(data: dict[str, NDArray[Any]], model: str, name: str, models_dir: Path, meta: dict[str, Any],
           table: dict[str, Any], replay: tuple[NDArray[np.uint8], NDArray[np.float64]] | None = None) -> Path:
    """model fine-tuned on every record, written as models_dir/NAME.onnx, .pt and .json (model's card with this
    training's data, recipe and the cross-validated table); the ONNX graph checked against torch."""
    net = fine_tune_soup(resolve_weights(model), data["images"], data["target"], seed=0, seeds=meta.get("seeds", 1),
                         epochs=meta["epochs"], lr=meta["learning_rate"], replay=replay)
    net = mix_weights(load_weights(resolve_weights(model)), net, meta["mix"])
    onnx_path = export_onnx(net, models_dir / f"{name}.onnx", channels=int(data["images"].shape[1]))
    save_weights(net, models_dir / f"{name}.pt", "fast", int(data["images"].shape[1]), 60, {})
    card = json.loads(resolve_weights(model).with_suffix(".json").read_text())
    card.pop("calibration", None)
    card.pop("metrics", None)
    card["name"] = name
    card["output"]["meaning"] = ("share of the grasp's lifts in physics that hold when the hand lands 2 mm / 3 degrees "
                                 f"off (fine-tuned from {model} on bench/oracle.py --perturb records; not calibrated)")
    card["training"] = {"init_from": model, "records": meta["records"], "images": meta["images"],
                        "detections": meta["detections"], "epochs": meta["epochs"],
                        "learning_rate": meta["learning_rate"], "mix": meta["mix"], "seeds": meta.get("seeds", 1),
                        "replay": meta.get("replay", []), "replay_rows": meta.get("replay_rows", 0),
                        "batch_size": BATCH, "target": "(held + N x share of perturbed copies held) / (N + 1)"}
    card["metrics"] = {"cross_validated_choice": table, "folds": meta["folds"], "folds_by": meta["folds_by"]}
    card["command"] = meta["command"]
    card["parity_max_abs_diff"] = check_parity(net, onnx_path, card, data["images"][:256], PARITY_TOLERANCE)
    return write_card(models_dir / f"{name}.json", card, REPO)


def report(meta: dict[str, Any], table: dict[str, Any], kinds: dict[str, Any]) -> str:
    header = ("| choice among each detection's tried grasps | detections | its lift held | share of its perturbed "
              "copies that held |")
    lines = ["# Can the classifier learn which of its top grasps hold: a cross-validated fine-tune", "",
             f"- command: `{meta['command']}`", f"- commit: `{meta['commit']}`, date {meta['date']}",
             f"- records: {', '.join(meta['records'])}", f"- {meta['images']} tried grasps in {meta['detections']} "
             f"detections; {meta['folds']} folds by {meta['folds_by']}; fine-tune of {meta['model']}: "
             f"{meta['epochs']} epochs, learning rate {meta['learning_rate']}, target the share of the grasp's 1 + N "
             f"lifts that held; weights {meta['mix']:g} x the fine-tune's + {1 - meta['mix']:g} x {meta['model']}'s"
             + (f"; each epoch replays as many of the {meta['replay_rows']} labelled rows of "
                f"{', '.join(meta['replay'])}" if meta.get("replay") else "")
             + (f"; each model the weight average of {meta['seeds']} fine-tunes of different seeds"
                if meta.get("seeds", 1) > 1 else ""), "", header, "|---|---|---|---|"]
    for name, t in table.items():
        lines.append(f"| {name} | {t['detections']} | {100 * t['held']:.1f}% | {100 * t['robust']:.1f}% |")
    if len(kinds) > 1:
        for kind, rows in kinds.items():
            lines += ["", f"## {kind}", "", header, "|---|---|---|---|"]
            lines += [f"| {name} | {t['detections']} | {100 * t['held']:.1f}% | {100 * t['robust']:.1f}% |"
                      for name, t in rows.items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=Path, nargs="*", default=[], help="bench/oracle.py --images files")
    ap.add_argument("--records", type=Path, nargs="*", default=[],
                    help="the same runs' bench/oracle.py JSON records, in the same order")
    ap.add_argument("--dir", type=Path, nargs="*", default=[], help="folders of bench/tried_chunks.py chunks")
    ap.add_argument("--model", default="household15", help="the model fine-tuned (models/NAME.pt)")
    ap.add_argument("--folds", type=int, default=5)
    ap.add_argument("--folds-by", choices=("seed", "object"), default="seed")
    ap.add_argument("--epochs", type=int, default=EPOCHS)
    ap.add_argument("--learning-rate", type=float, default=LEARNING_RATE)
    ap.add_argument("--mix", type=float, default=MIX,
                    help="share of the fine-tuned weights in the result, the rest the starting model's (0 < MIX <= 1)")
    ap.add_argument("--seeds", type=int, default=1,
                    help="fine-tunes (seeds) averaged weight for weight into each fold's model and the export")
    ap.add_argument("--replay", type=Path, nargs="*", default=[],
                    help="grasp-image datasets (scene_data) whose rows, with their labels, join every epoch")
    ap.add_argument("--tag", default="household-training")
    ap.add_argument("--out", type=Path, default=REPO / "bench" / "results")
    ap.add_argument("--export", default=None, help="also fine-tune on every record and write models/NAME.*")
    ap.add_argument("--models-dir", type=Path, default=REPO / "models")
    args = ap.parse_args(argv)
    if len(args.images) != len(args.records):
        ap.error("--images and --records must name the same runs, in the same order")
    for folder in args.dir:
        images, records = chunk_files(folder)
        args.images += images
        args.records += records
    if not args.records:
        ap.error("no records: name --images and --records, or --dir")
    if not 0.0 < args.mix <= 1.0:
        ap.error(f"--mix {args.mix}: must be in (0, 1]")
    if args.seeds < 1:
        ap.error(f"--seeds {args.seeds}: must be 1 or more")
    torch.set_num_threads(2)
    data = load_tried(args.images, args.records)
    replay = load_replay(args.replay)
    table, kinds, _ = evaluate(data, args.model, args.folds, args.folds_by, args.epochs, args.learning_rate, args.mix,
                               replay, args.seeds)
    meta = {"command": "PYTHONPATH=service:client:lab .venv/bin/python bench/reranker.py "
            + shlex.join(sys.argv[1:] if argv is None else argv), "commit": clutter.git_commit(),
            "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), "model": args.model, "folds": args.folds,
            "folds_by": args.folds_by, "epochs": args.epochs, "learning_rate": args.learning_rate, "mix": args.mix,
            "seeds": args.seeds, "replay": [str(p) for p in args.replay], "replay_rows": int(len(replay[1])),
            "records": [str(p) for p in args.records], "images": int(len(data["target"])),
            "detections": int(len(np.unique(data["detection"])))}
    md = report(meta, table, kinds)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"reranker-{args.tag}.md").write_text(md)
    result = {"meta": meta, "table": table, "kinds": kinds}
    (args.out / f"reranker-{args.tag}.json").write_text(json.dumps(result, indent=1))
    print(md)
    if args.export:
        print(f"wrote {export(data, args.model, args.export, args.models_dir, meta, table, replay)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
