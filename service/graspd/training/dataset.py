"""Labelled grasp-image datasets made from meshes: the on-disk format, a reader, and the generator.

On-disk format (one directory per dataset; the training code reads it with load_split / iter_chunks):

  DIR/manifest.json        format, seed, parameters, hand geometry, image size, representation,
                           objects, views, chunks (file name, rows, sha256), counts; see below.
  DIR/chunk_00000.npz ...  np.savez_compressed, rows in generation order, each file holds
      images      uint8 (M, 15, 60, 60)  channels first, graspd.images.encode_images(..., "15")
      labels      uint8 (M,)             1 = grasp (antipodal under graspd.training.labels), 0 = not
      object_ids  int32 (M,)             index into manifest["objects"]
      view_ids    int32 (M,)             view index within its object (0 .. views_per_object - 1)
      categories  uint8 (M,)             0 = box, 1 = cylinder, 2 = other (CATEGORIES)
      positions   float32 (M, 3)         hand base centre (m, object/world frame of the view)
      rotations   float32 (M, 3, 3)      columns [approach, binormal, axis]
      widths      float32 (M,)           object extent between the fingers (m)
  DIR/splits/view.json     the paper's split over views: {"kind": "view", "train"|"val"|"test":
                           [[object_id, view_id], ...]}; every object appears in every part,
                           no (object, view) pair in two parts.
  DIR/splits/object.json   split over objects: {"kind": "object", "train"|"val"|"test": [object_id, ...]}.

Only the 15-channel images are stored; the other representations are channel subsets of them
(derive_images): "12" drops the three unobserved channels, "3" keeps the normals seen along the hand
axis, "herzog" keeps the occupied and unobserved depth along the approach and adds free = neither.
Labels are balanced per object (as in the IJRR paper: surplus of the majority class discarded).

manifest.json keys: format ("graspd-grasp-images/1"), seed, representation ("15"), derivable
(["15", "12", "3", "herzog"]), image_size (60), channels (graspd.images.channel_layout("15")),
hand (HandGeometry.to_dict()), parameters (render, noise, preprocess, sampling, label settings),
objects ([{id, name, source, category, scale, extent}]), views ([{object_id, view_id, cameras,
num_points, num_candidates, num_positive, num_negative, kept}]), chunks ([{file, rows, sha256}]),
counts ({total, positive, negative, by_category}), dataset_sha256 (over the chunk hashes in order).

Objects 900-999 of pybullet_data random_urdfs are never used (graspd.training.objects refuses them).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

FORMAT = "graspd-grasp-images/1"
CATEGORIES: dict[str, int] = {"box": 0, "cylinder": 1, "other": 2}
STORED_REPRESENTATION = "15"
DERIVABLE = ("15", "12", "3", "herzog")
CHUNK_KEYS = ("images", "labels", "object_ids", "view_ids", "categories", "positions", "rotations", "widths")

# Channel indices into the stored 15 channels (layout of graspd.images.channel_layout("15")):
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
