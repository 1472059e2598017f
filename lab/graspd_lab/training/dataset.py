"""Labelled grasp-image datasets made from meshes: the on-disk format, a reader, and the generator.

On-disk format (one directory per dataset; the training code reads it with load_split / iter_chunks):

  DIR/manifest.json        format, seed, parameters, hand geometry, image size, representation,
                           objects, views, chunks (file name, rows, sha256), counts; see below.
  DIR/chunk_00000.npz ...  deflated .npz (np.load reads it; fixed zip timestamps so equal data gives
                           equal sha256), a group of whole objects per chunk, each file holds
      images      uint8 (M, 15, 60, 60)  channels first, graspd.gpd.images.encode_images(..., "15")
      labels      uint8 (M,)             1 = grasp (antipodal under graspd_lab.training.labels), 0 = not
      object_ids  int32 (M,)             index into manifest["objects"]
      view_ids    int32 (M,)             view index within its object (0 .. views_per_object - 1)
      categories  uint8 (M,)             0 = box, 1 = cylinder, 2 = other (CATEGORIES)
      positions   float32 (M, 3)         hand base centre (m, object/world frame of the view)
      rotations   float32 (M, 3, 3)      columns [approach, binormal, axis]
      widths      float32 (M,)           GraspSet.widths: extent of the observed points between fingers (m)
  DIR/splits/view.json     the paper's split over views: {"kind": "view", "train"|"val"|"test":
                           [[object_id, view_id], ...]}; every object appears in every part,
                           no (object, view) pair in two parts.
  DIR/splits/object.json   split over objects: {"kind": "object", "train"|"val"|"test": [object_id, ...]}.

Only the 15-channel images are stored; the other representations are channel subsets of them
(derive_images): "12" drops the three unobserved channels, "3" keeps the normals seen along the hand
axis, "herzog" keeps the occupied and unobserved depth along the approach and adds free = neither.
Labels are balanced per view, hence per object (as in the IJRR paper: surplus of the majority class
discarded); within a view the positive rows come first.

manifest.json keys: format ("graspd-grasp-images/1"), seed, representation ("15"), derivable
(["15", "12", "3", "herzog"]), image_size (60), channels (graspd.gpd.images.channel_layout("15")),
hand (HandGeometry.to_dict()), parameters (render, noise, preprocess, sampling, label settings),
objects ([{id, name, source, category, scale, extent}, or {id, name, source, category, skipped: reason}
for a broken source mesh, which then has no views]), views ([{object_id, view_id, cameras, num_points,
num_candidates, num_labelled, num_positive, num_negative (among the labelled), kept}]),
chunks ([{file, rows, positive, sha256}]), counts ({total, positive, negative, by_category, target}),
per_view (the quota), dataset_sha256 (sha256 of the chunk hashes concatenated in order), command.
timing.json beside it holds the generation time and exemplars per minute (not part of the hashes).
Resumable: each chunk's record (chunk_NNNNN.npz.json) is written beside it; rerunning the same command after an
interruption keeps the chunks already written (params.json holds the run's parameters).  The chunks run
serially, on a pool of --workers processes or as Ray tasks (--ray, --address; graspd_lab.cluster): the same
bytes whichever.

Objects 900-999 of pybullet_data random_urdfs are never used (graspd_lab.world.objects refuses them).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
import zipfile
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from graspd.core.camera import PAPER_CAMERA_SEPARATION_DEG, Camera, random_view
from graspd.core.cloud import ViewpointCloud
from graspd.core.grasp import GraspSet
from graspd.core.hand import HAND_PRESETS, HandGeometry, hand_preset
from graspd.core.progress import Progress
from graspd.gpd.candidates import SamplingParams, sample_candidates
from graspd.gpd.images import channel_layout, encode_images
from graspd.gpd.preprocess import PreprocessParams, preprocess
from graspd.gpd.scene import Scene
from graspd.viz.plot import gripper_segments
from graspd_lab.cluster import RayMissingError, Runner, imap, runner_from_args
from graspd_lab.cluster import add_arguments as add_cluster_arguments
from graspd_lab.training.labels import LabelParams, label_grasps, normal_slack_deg
from graspd_lab.world.noise import DepthNoise
from graspd_lab.world.objects import PROCEDURAL_KINDS, GraspObject, load_object, object_catalogue
from graspd_lab.world.render import MeshScene, render_scene

FORMAT = "graspd-grasp-images/1"
CATEGORIES: dict[str, int] = {"box": 0, "cylinder": 1, "other": 2}
STORED_REPRESENTATION = "15"
DERIVABLE = ("15", "12", "3", "herzog")
CHUNK_KEYS = ("images", "labels", "object_ids", "view_ids", "categories", "positions", "rotations", "widths")

# Channel indices into the stored 15 channels (layout of graspd.gpd.images.channel_layout("15")):
# projection p in (x, y, z) occupies channels 5p .. 5p+4 = nx, ny, nz, occ, unobs.
_SUBSETS: dict[str, list[int]] = {
    "15": list(range(15)),
    "12": [c for c in range(15) if c % 5 != 4],
    "3": [10, 11, 12],
}


def derive_images(images15: NDArray[np.uint8], representation: str) -> NDArray[np.uint8]:
    """Images of a representation (M, C, S, S) from stored 15-channel images (M, 15, S, S)."""
    if images15.ndim != 4 or images15.shape[1] != 15:
        raise ValueError(f"images15 must have shape (M, 15, S, S), got {images15.shape}")
    if representation in _SUBSETS:
        return np.ascontiguousarray(images15[:, _SUBSETS[representation]])
    if representation == "herzog":
        occ, unobs = images15[:, 3], images15[:, 4]
        free = np.where((occ > 0) | (unobs > 0), 0, 255).astype(np.uint8)
        return np.ascontiguousarray(np.stack([occ, unobs, free], axis=1))
    raise KeyError(f"unknown representation {representation!r}; known: {list(DERIVABLE)}")


def read_manifest(directory: str | Path) -> dict[str, Any]:
    """The dataset's manifest.json as a dict (ValueError if the format is not ours)."""
    path = Path(directory) / "manifest.json"
    manifest: dict[str, Any] = json.loads(path.read_text())
    if manifest.get("format") != FORMAT:
        raise ValueError(f"{path}: format must be {FORMAT!r}, got {manifest.get('format')!r}")
    return manifest


def read_split(directory: str | Path, kind: str) -> dict[str, Any]:
    """splits/<kind>.json ("view" or "object")."""
    if kind not in ("view", "object"):
        raise ValueError(f"split kind must be 'view' or 'object', got {kind!r}")
    split: dict[str, Any] = json.loads((Path(directory) / "splits" / f"{kind}.json").read_text())
    return split


def split_mask(object_ids: NDArray[np.int32], view_ids: NDArray[np.int32], split: dict[str, Any],
               part: str) -> NDArray[np.bool_]:
    """Rows (M,) that belong to part ("train", "val" or "test") of a split read by read_split."""
    if part not in ("train", "val", "test"):
        raise ValueError(f"split part must be 'train', 'val' or 'test', got {part!r}")
    members = split[part]
    if split["kind"] == "object":
        return np.isin(object_ids, np.asarray(members, np.int64))
    pairs = np.asarray(members, np.int64).reshape(-1, 2)
    key = object_ids.astype(np.int64) << 32 | view_ids.astype(np.int64)
    return np.isin(key, pairs[:, 0] << 32 | pairs[:, 1])


def sha256_file(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def iter_chunks(directory: str | Path, verify: bool = False) -> Iterator[dict[str, NDArray[Any]]]:
    """The chunks of a dataset in order, each a dict of CHUNK_KEYS arrays; verify checks sha256."""
    directory = Path(directory)
    for entry in read_manifest(directory)["chunks"]:
        path = directory / entry["file"]
        if verify and sha256_file(path) != entry["sha256"]:
            raise ValueError(f"{path}: sha256 does not match the manifest")
        with np.load(path) as z:
            yield {k: z[k] for k in CHUNK_KEYS}


def load_split(directory: str | Path, kind: str = "view", part: str = "train", representation: str = "15",
               categories: tuple[str, ...] | None = None) -> dict[str, NDArray[Any]]:
    """All rows of one part of a split, images derived to a representation, optionally only some
    categories; a dict with the CHUNK_KEYS arrays."""
    split = read_split(directory, kind)
    cat_codes = None if categories is None else np.array([CATEGORIES[c] for c in categories], np.uint8)
    parts: dict[str, list[NDArray[Any]]] = {k: [] for k in CHUNK_KEYS}
    for chunk in iter_chunks(directory):
        mask = split_mask(chunk["object_ids"], chunk["view_ids"], split, part)
        if cat_codes is not None:
            mask &= np.isin(chunk["categories"], cat_codes)
        if not mask.any():
            continue
        for k in CHUNK_KEYS:
            value = chunk[k][mask]
            parts[k].append(derive_images(value, representation) if k == "images" else value)
    if not parts["labels"]:
        raise ValueError(f"split {kind!r} part {part!r} has no rows in {directory}")
    return {k: np.concatenate(v) for k, v in parts.items()}


# ---------------------------------------------------------------------------------------------------
# Generation: object -> views -> render -> preprocess -> scene -> candidates -> labels -> images.
# ---------------------------------------------------------------------------------------------------

_LABEL_BATCH = 192
DEFAULT_PROCEDURAL: dict[str, int] = {"box": 150, "cylinder": 150, "sphere": 40, "cone": 40, "capsule": 40,
                                      "composite": 80}


@dataclass(frozen=True)
class GenerationParams:
    """Everything that determines a dataset (with the code): seed, size target, objects, views, sampling
    (rounds of num_samples cloud points, at most max_samples per view), sensor noise and labels.
    per_view is the most exemplars kept per view (half positives); None derives it from
    exemplars / (objects x views) with a margin for views short of positives."""

    seed: int = 0
    exemplars: int = 200_000
    num_urdfs: int = 900
    procedural: tuple[tuple[str, int], ...] = tuple(DEFAULT_PROCEDURAL.items())
    views_per_object: int = 8
    single_camera_fraction: float = 0.25
    camera_distance: tuple[float, float] = (0.5, 0.8)
    camera_separation_deg: float = PAPER_CAMERA_SEPARATION_DEG
    num_samples: int = 50
    max_samples: int = 250
    per_view: int | None = None
    margin: float = 1.1
    objects_per_chunk: int = 16
    hand: HandGeometry = field(default_factory=HandGeometry)
    noise: DepthNoise = field(default_factory=DepthNoise)
    preprocess: PreprocessParams = field(default_factory=PreprocessParams)
    sampling: SamplingParams = field(default_factory=SamplingParams)
    labels: LabelParams = field(default_factory=LabelParams)
    split_fractions: tuple[float, float] = (0.15, 0.10)  # (test, val) for both splits

    def __post_init__(self) -> None:
        if self.exemplars <= 0:
            raise ValueError(f"exemplars must be positive, got {self.exemplars}")
        if self.views_per_object < 3:
            raise ValueError(f"views_per_object must be >= 3 (train, val and test views), got {self.views_per_object}")
        if not 0.0 <= self.single_camera_fraction <= 1.0:
            raise ValueError(f"single_camera_fraction must lie in [0, 1], got {self.single_camera_fraction}")
        if self.num_samples <= 0 or self.max_samples < self.num_samples:
            raise ValueError(f"num_samples must be positive and max_samples >= num_samples, got "
                             f"{self.num_samples} and {self.max_samples}")
        if self.objects_per_chunk <= 0:
            raise ValueError(f"objects_per_chunk must be positive, got {self.objects_per_chunk}")

    def object_specs(self) -> list[tuple[str, int]]:
        """(kind, index) of every object, in a seeded order that mixes the kinds across chunks."""
        specs = object_catalogue(self.num_urdfs, dict(self.procedural))
        order = np.random.default_rng([self.seed, 1]).permutation(len(specs))
        return [specs[i] for i in order]

    def quota(self, num_objects: int) -> int:
        """Exemplars kept per view (even: half positives, half negatives)."""
        if self.per_view is not None:
            return max(2, 2 * (self.per_view // 2))
        raw = self.margin * self.exemplars / max(num_objects * self.views_per_object, 1)
        return max(2, 2 * int(np.ceil(raw / 2)))

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["procedural"] = dict(self.procedural)
        return d


def _render_view(scene: MeshScene, object_id: int, view_id: int, params: GenerationParams
                 ) -> tuple[np.random.Generator, list[Camera], ViewpointCloud]:
    """The view's seeded generator (after rendering), its cameras and the cloud they see."""
    rng = np.random.default_rng([params.seed, 2, object_id, view_id])
    num_cameras = 1 if rng.random() < params.single_camera_fraction else 2
    cameras = random_view(rng, None, num_cameras, params.camera_distance, params.camera_separation_deg)
    return rng, cameras, render_scene(scene, cameras, params.noise, rng)


def _view_exemplars(obj: GraspObject, scene: MeshScene, object_id: int, view_id: int, quota: int,
                    params: GenerationParams) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """Balanced labelled grasp images of one view of one object, and the view's manifest record."""
    rng, cameras, cloud = _render_view(scene, object_id, view_id, params)
    record: dict[str, Any] = {"object_id": object_id, "view_id": view_id,
                              "cameras": [list(map(float, c.position)) for c in cameras],
                              "num_points": len(cloud), "num_candidates": 0, "num_labelled": 0, "num_positive": 0,
                              "num_negative": 0, "kept": 0}
    empty = _empty_rows()
    if len(cloud) < 10:
        return empty, record
    oriented = preprocess(cloud, params.preprocess)
    gscene = Scene.build(oriented, params.hand)
    # Sample in rounds of num_samples cloud points (a seeded permutation, up to max_samples) and label the
    # candidates in random order, a batch at a time, until both classes fill their half of the quota: per
    # class the same uniform choice as labelling everything, at a fraction of the cost for easy objects,
    # and more candidates for objects with few grasps (boxes).
    half = quota // 2
    points = rng.permutation(len(oriented))
    pos: list[GraspSet] = []
    neg: list[GraspSet] = []
    n_pos = n_neg = labelled = candidates = 0
    for r0 in range(0, min(len(points), params.max_samples), params.num_samples):
        idx = np.sort(points[r0 : min(r0 + params.num_samples, params.max_samples)])
        sampling = replace(params.sampling, sample_indices=tuple(int(i) for i in idx))
        grasps = sample_candidates(gscene, params.hand, sampling)
        candidates += len(grasps)
        order = rng.permutation(len(grasps))
        for start in range(0, len(order), _LABEL_BATCH):
            batch = grasps[order[start : start + _LABEL_BATCH]]
            lab = label_grasps(scene, batch, params.hand, params.labels)
            pos.append(batch[lab.grasp])
            neg.append(batch[~lab.grasp])
            n_pos, n_neg = n_pos + int(lab.grasp.sum()), n_neg + int((~lab.grasp).sum())
            labelled += len(batch)
            if n_pos >= half and n_neg >= half:
                break
        if n_pos >= half and n_neg >= half:
            break
    record.update(num_candidates=candidates, num_labelled=labelled, num_positive=n_pos, num_negative=n_neg)
    k = min(half, n_pos, n_neg)
    if k == 0:
        return empty, record
    chosen = GraspSet.concatenate([GraspSet.concatenate(pos)[:k], GraspSet.concatenate(neg)[:k]])
    labels = np.repeat(np.array([1, 0], np.uint8), k)
    images = encode_images(gscene, chosen, params.hand, STORED_REPRESENTATION)
    record["kept"] = 2 * k
    rows: dict[str, NDArray[Any]] = {
        "images": images,
        "labels": labels,
        "object_ids": np.full(2 * k, object_id, np.int32),
        "view_ids": np.full(2 * k, view_id, np.int32),
        "categories": np.full(2 * k, CATEGORIES[obj.category], np.uint8),
        "positions": chosen.positions.astype(np.float32),
        "rotations": chosen.rotations.astype(np.float32),
        "widths": chosen.widths.astype(np.float32),
    }
    return rows, record


def _empty_rows(size: int = 60) -> dict[str, NDArray[Any]]:
    return {"images": np.zeros((0, 15, size, size), np.uint8), "labels": np.zeros(0, np.uint8),
            "object_ids": np.zeros(0, np.int32), "view_ids": np.zeros(0, np.int32),
            "categories": np.zeros(0, np.uint8), "positions": np.zeros((0, 3), np.float32),
            "rotations": np.zeros((0, 3, 3), np.float32), "widths": np.zeros(0, np.float32)}


def write_npz(path: Path, arrays: dict[str, NDArray[Any]]) -> str:
    """A deflated (level 1) .npz readable by np.load, byte-identical for identical arrays (fixed zip timestamps);
    returns its sha256."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key, value in arrays.items():
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info._compresslevel = 1  # type: ignore[attr-defined]  # 5x faster than 6, 15% vs 13% of raw size
            with zf.open(info, "w", force_zip64=True) as f:
                np.lib.format.write_array(f, np.ascontiguousarray(value), allow_pickle=False)
    return sha256_file(path)


def _generate_chunk(task: tuple[int, list[tuple[int, str, int]], int, GenerationParams, str]
                    ) -> tuple[int, list[dict[str, Any]], list[dict[str, Any]], dict[str, Any]]:
    """Worker: all views of a group of objects -> one chunk file; returns (chunk index, object records,
    view records, chunk entry); a chunk whose record an earlier, interrupted run wrote is not made again."""
    chunk_index, group, quota, params, out_dir = task
    done = Path(out_dir) / f"chunk_{chunk_index:05d}.npz.json"
    if done.exists():
        saved = json.loads(done.read_text())
        return chunk_index, saved["objects"], saved["views"], saved["entry"]
    objects, views, parts = [], [], []
    for object_id, kind, index in group:
        try:
            obj = load_object(kind, index, params.seed, params.hand)
        except ValueError as exc:  # a broken source mesh (random_urdfs/168 has NaN vertices): no views
            objects.append({"id": object_id, "name": f"{kind}_{index:03d}", "source": kind, "category": "other",
                            "skipped": str(exc)})
            continue
        scene = MeshScene([obj.mesh])
        objects.append({"id": object_id, **obj.to_dict()})
        for view_id in range(params.views_per_object):
            rows, record = _view_exemplars(obj, scene, object_id, view_id, quota, params)
            views.append(record)
            parts.append(rows)
    arrays = {k: np.concatenate([p[k] for p in [_empty_rows(), *parts]]) for k in CHUNK_KEYS}
    name = f"chunk_{chunk_index:05d}.npz"
    digest = write_npz(Path(out_dir) / name, arrays)
    labels = arrays["labels"]
    entry = {"file": name, "rows": int(len(labels)), "positive": int(labels.sum()), "sha256": digest}
    done.write_text(json.dumps({"objects": objects, "views": views, "entry": entry}))
    return chunk_index, objects, views, entry


def _splits(objects: list[dict[str, Any]], views_per_object: int, fractions: tuple[float, float], seed: int
            ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The view split (per object: test, val and train views) and the object split (per category)."""
    f_test, f_val = fractions
    n_test_v = max(1, int(round(f_test * views_per_object)))
    n_val_v = max(1, int(round(f_val * views_per_object)))
    view: dict[str, Any] = {"kind": "view", "train": [], "val": [], "test": []}
    for o in objects:
        perm = np.random.default_rng([seed, 3, o["id"]]).permutation(views_per_object)
        view["test"] += [[o["id"], int(v)] for v in sorted(perm[:n_test_v])]
        view["val"] += [[o["id"], int(v)] for v in sorted(perm[n_test_v : n_test_v + n_val_v])]
        view["train"] += [[o["id"], int(v)] for v in sorted(perm[n_test_v + n_val_v :])]
    obj: dict[str, Any] = {"kind": "object", "train": [], "val": [], "test": []}
    for cat in CATEGORIES:
        ids = np.array([o["id"] for o in objects if o["category"] == cat], np.int64)
        if len(ids) == 0:
            continue
        ids = ids[np.random.default_rng([seed, 4, CATEGORIES[cat]]).permutation(len(ids))]
        n_test = max(1, int(round(f_test * len(ids)))) if len(ids) >= 3 else 0
        n_val = max(1, int(round(f_val * len(ids)))) if len(ids) >= 3 else 0
        obj["test"] += sorted(int(i) for i in ids[:n_test])
        obj["val"] += sorted(int(i) for i in ids[n_test : n_test + n_val])
        obj["train"] += sorted(int(i) for i in ids[n_test + n_val :])
    for part in ("train", "val", "test"):
        obj[part] = sorted(obj[part])
    return view, obj


def generate_dataset(out_dir: str | Path, params: GenerationParams, workers: int = 2,
                     progress: bool = False, runner: Runner | None = None) -> dict[str, Any]:
    """Write a dataset (format above) to out_dir and return its manifest; deterministic from params
    (the same params give the same chunk hashes whatever the number of workers or the runner).  Rerun after
    an interruption, it keeps the chunks already written.  runner: graspd_lab.cluster (serial, a pool, Ray
    tasks); default: a fork pool of `workers`."""
    runner = runner or Runner(workers=max(1, workers), context="fork")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    saved = out / "params.json"
    if (out / "manifest.json").exists() or (any(out.glob("chunk_*.npz")) and not saved.exists()):
        raise FileExistsError(f"{out} already holds a dataset; choose an empty --out folder")
    if saved.exists() and json.loads(saved.read_text()) != json.loads(json.dumps(params.to_dict())):
        raise FileExistsError(f"{out} holds chunks of a run with other parameters; choose an empty --out folder")
    saved.write_text(json.dumps(params.to_dict(), indent=1))
    specs = params.object_specs()
    quota = params.quota(len(specs))
    tasks = []
    g = params.objects_per_chunk
    for c, start in enumerate(range(0, len(specs), g)):
        group = [(start + i, kind, index) for i, (kind, index) in enumerate(specs[start : start + g])]
        tasks.append((c, group, quota, params, str(out)))
    t0 = time.perf_counter()
    results: list[tuple[int, list[dict[str, Any]], list[dict[str, Any]], dict[str, Any]]] = []
    results = _collect(imap(_generate_chunk, tasks, runner), len(tasks), t0, progress)
    elapsed = time.perf_counter() - t0
    results.sort(key=lambda r: r[0])
    missing = [r[3]["file"] for r in results if not (out / r[3]["file"]).is_file()]
    if missing:  # Ray workers on other nodes wrote them into a folder of their own
        raise FileNotFoundError(f"chunks {missing[:3]} were written elsewhere: on a Ray cluster --out must be a "
                                "folder every node sees (a shared file system)")
    objects = [o for r in results for o in r[1]]
    views = [v for r in results for v in r[2]]
    chunks = [r[3] for r in results]
    view_split, object_split = _splits(objects, params.views_per_object, params.split_fractions, params.seed)
    (out / "splits").mkdir(exist_ok=True)
    (out / "splits" / "view.json").write_text(json.dumps(view_split))
    (out / "splits" / "object.json").write_text(json.dumps(object_split))
    total = sum(c["rows"] for c in chunks)
    positive = sum(c["positive"] for c in chunks)
    by_category = {cat: 0 for cat in CATEGORIES}
    for v in views:
        by_category[objects[v["object_id"]]["category"]] += int(v["kept"])
    manifest = {
        "format": FORMAT,
        "seed": params.seed,
        "representation": STORED_REPRESENTATION,
        "derivable": list(DERIVABLE),
        "image_size": 60,
        "channels": channel_layout(STORED_REPRESENTATION),
        "hand": params.hand.to_dict(),
        "label_normal_slack_deg": normal_slack_deg(params.hand, params.labels),
        "parameters": params.to_dict(),
        "per_view": quota,
        "objects": objects,
        "views": views,
        "chunks": chunks,
        "counts": {"total": total, "positive": positive, "negative": total - positive, "by_category": by_category,
                   "target": params.exemplars},
        "dataset_sha256": chunks_sha256(chunks),
        "command": command_line(params, str(out)),
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    (out / "timing.json").write_text(json.dumps({"seconds": elapsed, "workers": runner.workers,
                                                 "runner": runner.describe(), "exemplars": total,
                                                 "exemplars_per_minute": 60.0 * total / max(elapsed, 1e-9)}))
    return manifest


def chunks_sha256(chunks: list[dict[str, Any]]) -> str:
    """A dataset's dataset_sha256: sha256 of its chunk hashes concatenated in order."""
    return hashlib.sha256("".join(c["sha256"] for c in chunks).encode()).hexdigest()


def _collect(results: Iterator[Any], n: int, t0: float, progress: bool) -> list[Any]:
    """The n chunk results, in the order they come; progress: a graspd.core.progress display of the chunks (a bar
    on a terminal, a line a minute in a log) with the exemplars written and their rate."""
    out = []
    rows = 0
    with Progress(n, "dataset chunks", "chunk", mode=None if progress else "off") as bar:
        for r in results:
            out.append(r)
            rows += r[3]["rows"]
            dt = time.perf_counter() - t0
            bar.update(1, exemplars=rows, per_min=round(60 * rows / max(dt, 1e-9)))
    return out


def command_line(params: GenerationParams, out: str) -> str:
    """The command that regenerates a dataset with these parameters (non-default hand/noise/labels aside)."""
    proc = ",".join(f"{k}={v}" for k, v in params.procedural)
    parts = ["python -m graspd_lab.training.dataset", f"--out {out}", f"--exemplars {params.exemplars}",
             f"--seed {params.seed}", "--representation 15", f"--urdfs {params.num_urdfs}",
             f"--procedural {proc or 'none'}", f"--views {params.views_per_object}",
             f"--samples {params.num_samples}", f"--max-samples {params.max_samples}",
             f"--single-camera-fraction {params.single_camera_fraction}"]
    if params.per_view is not None:
        parts.append(f"--per-view {params.per_view}")
    if params.labels.mu is not None:
        parts.append(f"--mu {params.labels.mu}")
    return " ".join(parts)


def write_preview(directory: str | Path, path: str | Path, object_id: int = 0, view_id: int = 0,
                  show: int = 6) -> Path:
    """A PNG to judge a dataset's labels by eye: one view's cloud (re-rendered from the manifest's
    parameters) with its stored grasps as grippers (green = grasp, red = not), seen from the first camera
    and from the side, the mesh's surface as grey dots, and the 15 channels of a few stored exemplars."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    directory = Path(directory)
    manifest = read_manifest(directory)
    params = _params_from_dict(manifest["parameters"])
    entry = manifest["objects"][object_id]
    kind, index = _spec_of(entry)
    obj = load_object(kind, index, params.seed, params.hand)
    _, cameras, cloud = _render_view(MeshScene([obj.mesh]), object_id, view_id, params)
    rows: dict[str, NDArray[Any]] | None = None
    for chunk in iter_chunks(directory):
        m = (chunk["object_ids"] == object_id) & (chunk["view_ids"] == view_id)
        if m.any():
            rows = {k: v[m] for k, v in chunk.items()}
            break
    if rows is None:
        raise ValueError(f"no exemplars of object {object_id} view {view_id} in {directory}")
    lab = rows["labels"].astype(bool)
    pick = np.concatenate([np.flatnonzero(lab)[: show // 2], np.flatnonzero(~lab)[: show // 2]])
    grasps = GraspSet(positions=rows["positions"][pick].astype(np.float64),
                      rotations=rows["rotations"][pick].astype(np.float64),
                      widths=rows["widths"][pick].astype(np.float64), scores=lab[pick].astype(np.float64),
                      samples=rows["positions"][pick].astype(np.float64))
    segs = gripper_segments(grasps, params.hand)
    tri = np.asarray(obj.mesh.triangles)
    verts = np.asarray(obj.mesh.vertices)
    bary = np.random.default_rng(0).dirichlet(np.ones(3), 4000)
    faces = np.random.default_rng(1).integers(0, len(tri), 4000)
    surface = np.einsum("nk,nkj->nj", bary, verts[tri[faces]])  # mesh surface samples (not area-weighted)
    rot = cameras[0].rotation()
    side = rot @ np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]).T  # camera turned 90 deg

    fig = plt.figure(figsize=(16, 4 + 1.3 * len(pick)), dpi=90)
    grid = fig.add_gridspec(1 + len(pick), 15, height_ratios=[4.0] + [1.3] * len(pick))
    for col, (basis, name) in enumerate(((rot, "camera 0"), (side, "side"))):
        ax = fig.add_subplot(grid[0, 7 * col : 7 * col + 7])
        for pts, size, colour in ((surface, 1.0, "0.8"), (cloud.points, 1.5, "tab:blue")):
            uv = (pts - np.asarray(cameras[0].position)) @ basis
            ax.scatter(uv[:, 0], -uv[:, 1], s=size, c=colour, linewidths=0)
        for k in range(len(pick)):
            colour = "limegreen" if lab[pick[k]] else "red"
            for seg in segs[k]:
                uv = (seg - np.asarray(cameras[0].position)) @ basis
                ax.plot(uv[:, 0], -uv[:, 1], color=colour, lw=2)
            c = (grasps.positions[k] - np.asarray(cameras[0].position)) @ basis
            ax.annotate(str(k), (c[0], -c[1]), fontsize=9, weight="bold")
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{entry['name']} view {view_id}, seen from {name} (orthographic)", fontsize=9)
    names = channel_layout(STORED_REPRESENTATION)
    for r, i in enumerate(pick):
        for c in range(15):
            ax = fig.add_subplot(grid[1 + r, c])
            ax.imshow(rows["images"][i, c], cmap="gray", vmin=0, vmax=255)
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(names[c], fontsize=7)
            if c == 0:
                ax.set_ylabel(f"{r}: {'grasp' if lab[i] else 'not'}", fontsize=8,
                              color="green" if lab[i] else "red")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def _spec_of(entry: dict[str, Any]) -> tuple[str, int]:
    """(kind, index) of a manifest object entry."""
    kind, _, index = entry["name"].rpartition("_")
    return ("urdf" if kind == "urdf" else kind), int(index)


def _params_from_dict(d: dict[str, Any]) -> GenerationParams:
    """GenerationParams from manifest["parameters"] (GenerationParams.to_dict)."""
    d = dict(d)
    d["procedural"] = tuple(d["procedural"].items())
    d["camera_distance"] = tuple(d["camera_distance"])
    d["split_fractions"] = tuple(d["split_fractions"])
    d["hand"] = HandGeometry(**d["hand"])
    d["noise"] = DepthNoise(**d["noise"])
    pre = dict(d["preprocess"])
    if pre.get("workspace") is not None:
        pre["workspace"] = tuple(pre["workspace"])
    d["preprocess"] = PreprocessParams(**pre)
    samp = dict(d["sampling"])
    if samp.get("sample_indices") is not None:
        samp["sample_indices"] = tuple(samp["sample_indices"])
    d["sampling"] = SamplingParams(**samp)
    d["labels"] = LabelParams(**d["labels"])
    return GenerationParams(**d)


def _parse_procedural(text: str) -> tuple[tuple[str, int], ...]:
    if text in ("", "none"):
        return ()
    out = []
    for item in text.split(","):
        kind, _, count = item.partition("=")
        if kind not in PROCEDURAL_KINDS or not count.isdigit():
            raise argparse.ArgumentTypeError(
                f"--procedural items must be KIND=COUNT with KIND in {PROCEDURAL_KINDS}, got {item!r}")
        out.append((kind, int(count)))
    return tuple(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m graspd_lab.training.dataset",
                                 description="Generate a labelled grasp-image dataset from meshes (see module doc).")
    ap.add_argument("--out", required=True, help="empty output folder")
    ap.add_argument("--exemplars", type=int, default=200_000, help="target number of exemplars (balanced)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--representation", default="15", choices=["15"],
                    help="stored representation; 12, 3 and herzog are derived from it when loading")
    ap.add_argument("--urdfs", type=int, default=900, help="use pybullet_data random_urdfs 000..N-1 (N <= 900)")
    ap.add_argument("--procedural", type=_parse_procedural,
                    default=tuple(DEFAULT_PROCEDURAL.items()),
                    help="procedural objects, e.g. box=150,cylinder=150,sphere=40 (or none)")
    ap.add_argument("--views", type=int, default=8, help="views per object")
    ap.add_argument("--samples", type=int, default=50,
                    help="cloud points sampled per round (Algorithm 2); more rounds while a class is short")
    ap.add_argument("--max-samples", type=int, default=250, help="most cloud points sampled per view")
    ap.add_argument("--per-view", type=int, default=None, help="exemplars kept per view (default: from --exemplars)")
    ap.add_argument("--single-camera-fraction", type=float, default=0.25,
                    help="fraction of views seen by one camera instead of two 53 deg apart")
    ap.add_argument("--hand", default="gpd", help=f"hand preset: {sorted(HAND_PRESETS)}")
    ap.add_argument("--mu", type=float, default=None, help="label with friction cones (default: frictionless)")
    ap.add_argument("--workers", type=int, default=2, help="processes (or Ray CPUs with --ray)")
    add_cluster_arguments(ap)
    ap.add_argument("--objects-per-chunk", type=int, default=16)
    ap.add_argument("--preview", metavar="PNG", help="also write a PNG of object 0, view 0 and its exemplars")
    args = ap.parse_args(argv)
    try:
        params = GenerationParams(
            seed=args.seed, exemplars=args.exemplars, num_urdfs=args.urdfs, procedural=args.procedural,
            views_per_object=args.views, num_samples=args.samples, max_samples=args.max_samples, per_view=args.per_view,
            single_camera_fraction=args.single_camera_fraction, hand=hand_preset(args.hand),
            labels=LabelParams(mu=args.mu), objects_per_chunk=args.objects_per_chunk)
        runner = runner_from_args(args, args.workers, context="fork")
    except (ValueError, KeyError, RayMissingError) as exc:
        ap.error(str(exc))
    manifest = generate_dataset(args.out, params, progress=True, runner=runner)
    timing = json.loads((Path(args.out) / "timing.json").read_text())
    c = manifest["counts"]
    print(f"{c['total']} exemplars ({c['positive']} positive) from {len(manifest['objects'])} objects x "
          f"{params.views_per_object} views in {timing['seconds']:.1f} s, {runner.describe()}: "
          f"{timing['exemplars_per_minute']:.0f} exemplars/min; dataset_sha256 {manifest['dataset_sha256']}")
    if args.preview:
        print(f"preview: {write_preview(args.out, args.preview)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
