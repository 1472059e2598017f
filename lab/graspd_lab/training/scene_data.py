"""Labelled grasp images from cluttered scenes, made as the service sees them.

One scene and camera model for training and evaluation: the clutter benchmark's pybullet scenes
(graspd_lab.sim.world.build_scene: objects poured into a tray, VGN piles, packed rows, single objects), its
cameras (two passive cameras 53 degrees apart, or one side camera) and its depth noise
(DepthNoise.benchmark()), with training objects only (random_urdfs 000-899; never 900-999).  Each scene is
seen several times while objects are taken out of it one at a time, as a robot clears it.

Household models (graspd_lab.world.household, at their true size, never a held-out one) join the scenes'
objects at household_share, and each scene may draw its sensor from sensor_mix (the Kinect model, an active-stereo
or a ToF camera: graspd_lab.world.noise); the defaults (no household models, the Kinect only) make the datasets
they always made.  --mix household is the retrain's mix: piles, packed scenes, trays and containers.

Every view is cropped to the benchmark's workspace box and goes through the detector's own stages
(GraspDetector.prepare and search with default DetectionParams): the candidates are exactly those the
service would score on that cloud.  Each is labelled against the true meshes of the objects, the floor
and the tray walls (graspd_lab.training.labels with graspable = objects only and the approach path checked):
positive only if its contacts are antipodal on one object and the hand, on its way in, hits nothing.  With
--slip-labels the kept positives are then lifted in physics by the benchmark's hand (graspd_lab.sim.lift, with the
objects' simulated mass and inertia) and stay positive only if the object does not slip: heavy or long objects
grasped far from their centre of mass turn or drop out of the fingers.

The output has the single-object dataset's format (graspd_lab.training.dataset: manifest.json, chunks,
splits/view.json and splits/object.json), so training, evaluation and the benchmarks read both; here a
manifest "object" is a scene.  The object split is over the objects themselves: training objects are
split 75/10/15 (seeded), and every scene draws all its objects from one part, so test-part scenes hold
only objects no training scene holds.  Rows are not balanced (every positive up to half the per-view
cap, up to three negatives per positive; training weights the classes): clutter has many more negatives
than positives, and the highest-scoring ones are what precision at the top depends on.

  PYTHONPATH=service python -m graspd_lab.training.scene_data --out DATA --scenes 600 --workers 2
  ... --workers 2 --ray              (Ray tasks on this machine; graspd-lab[cluster])
  ... --ray --address auto           (a Ray cluster; --out must be a folder every node sees)
  ... --mix household --household-share 0.5 --sensors mixed   (household models, mixed sensors)
  ... --slip-labels                  (positives must also hold through a lift in physics)

The chunks depend only on the parameters: one process, a pool or Ray write the same bytes (graspd_lab.cluster).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from graspd.core.camera import sensing_cameras
from graspd.core.grasp import GraspSet
from graspd.core.hand import HAND_PRESETS, HandGeometry, hand_preset
from graspd.gpd.detector import DetectionParams, GraspDetector
from graspd.gpd.environment import Environment, EnvironmentParams
from graspd.gpd.images import channel_layout, encode_images
from graspd.gpd.scene import ClosingRegionPoints
from graspd_lab.cluster import RayMissingError, Runner, imap, runner_from_args
from graspd_lab.cluster import add_arguments as add_cluster_arguments
from graspd_lab.training.dataset import (
    CHUNK_KEYS,
    DERIVABLE,
    FORMAT,
    STORED_REPRESENTATION,
    _collect,
    _empty_rows,
    chunks_sha256,
    write_npz,
)
from graspd_lab.training.labels import LabelParams, label_grasps
from graspd_lab.world import household
from graspd_lab.world.noise import DepthNoise, SensorNoise, draw_sensor, sensor_noise
from graspd_lab.world.objects import USABLE_TRAINING_URDFS, check_not_held_out
from graspd_lab.world.render import MeshScene

#: Scene kinds and their share of the scenes: the benchmark's trays and piles, packed rows, lone objects.
SCENE_MIX: tuple[tuple[str, float], ...] = (("pour", 0.4), ("pile", 0.35), ("packed", 0.1), ("single", 0.15))
#: Container scenes: the container family's training styles (graspd_lab.sim.containers.TRAINING_STYLES,
#: their training ranges) with objects dropped in, beside some of the benchmark's trays and piles.  A kind
#: "container:STYLE" draws the scene's container from its seed.
CONTAINER_MIX: tuple[tuple[str, float], ...] = (("container:tray", 0.2), ("container:deep_bin", 0.15),
                                                ("container:platform", 0.15), ("container:tote", 0.2),
                                                ("container:shelf", 0.1), ("pour", 0.1), ("pile", 0.1))
#: Household scenes: VGN's piles and packed scenes, the benchmark's trays, and the containers' training styles.
HOUSEHOLD_MIX: tuple[tuple[str, float], ...] = (("pile", 0.3), ("packed", 0.25), ("pour", 0.1),
                                                ("container:tray", 0.15), ("container:tote", 0.1),
                                                ("container:deep_bin", 0.05), ("container:platform", 0.05))
MIXES: dict[str, tuple[tuple[str, float], ...]] = {"clutter": SCENE_MIX, "containers": CONTAINER_MIX,
                                                   "household": HOUSEHOLD_MIX}
#: Sensors a scene is seen with, and their shares: the Kinect model only (the benchmark's), or all three.
SENSOR_MIXES: dict[str, tuple[tuple[str, float], ...]] = {
    "kinect": (("kinect", 1.0),), "mixed": (("kinect", 0.34), ("stereo", 0.33), ("tof", 0.33))}
#: Sensing and its share of the views: the benchmark's passive pair and one side camera.
SENSING_MIX: tuple[tuple[str, float], ...] = (("passive", 0.6), ("side", 0.4))
PARTS = ("train", "val", "test")


#: Friction coefficient of the scene labels: half the simulator's object friction (1.0), so a positive is a
#: force-closure grasp with margin; frictionless labels call most grasps of the faceted random_urdfs
#: blobs negative (7% vs 16% positive in the first test scene) though they hold in the simulator.
SCENE_LABEL_MU = 0.5


def scene_labels() -> LabelParams:
    """Scene labels: friction cones of SCENE_LABEL_MU, the hand's own palm, and the approach path the
    service keeps free (5 cm) checked too."""
    return LabelParams(mu=SCENE_LABEL_MU, palm_depth=None, approach_path=DetectionParams().approach_distance)


@dataclass(frozen=True)
class SceneParams:
    """Everything that determines a scene dataset (with the code): seed, how many scenes of which kinds,
    objects per scene (min, max), views per scene (one object removed between views), candidates per view
    (num_samples of the detector) and the most rows kept per view: every positive up to half of it, and
    negatives (a uniform draw) up to negatives_per_positive per positive, at least min_negatives.
    hard_negatives_per_view: hands the detector itself rejects (rim and wall pinches, grasps on the support,
    hands in unseen space) added to each view's candidates before the draw.  household_share: the expected share
    of a scene's objects that are household models (true size); sensor_mix: (sensor, weight) each scene's sensor
    is drawn from ("kinect" is `noise`, the others graspd_lab.world.noise.sensor_noise).  slip_labels: every kept
    positive is also lifted in physics (graspd_lab.sim.lift) and is 0 unless it holds the object without slipping.
    heavy_share: the expected share of a scene's household models drawn from the heavy ones
    (household.heavy_training_names: those that slip; 0: drawn uniformly, as before)."""

    seed: int = 0
    scenes: int = 600
    views_per_scene: int = 4
    objects: tuple[int, int] = (4, 10)
    scene_mix: tuple[tuple[str, float], ...] = SCENE_MIX
    sensing_mix: tuple[tuple[str, float], ...] = SENSING_MIX
    num_samples: int = 150
    per_view: int = 160
    negatives_per_positive: int = 3
    min_negatives: int = 20
    hard_negatives_per_view: int = 0
    scenes_per_chunk: int = 10
    part_fractions: tuple[float, float] = (0.15, 0.10)  # (test, val) of the objects and of the views
    hand: HandGeometry = field(default_factory=HandGeometry)
    noise: DepthNoise = field(default_factory=DepthNoise.benchmark)
    labels: LabelParams = field(default_factory=scene_labels)
    household_share: float = 0.0
    sensor_mix: tuple[tuple[str, float], ...] = SENSOR_MIXES["kinect"]
    slip_labels: bool = False
    heavy_share: float = 0.0

    def __post_init__(self) -> None:
        if self.scenes < 1 or self.views_per_scene < 1:
            raise ValueError(f"scenes and views_per_scene must be >= 1, got {self.scenes}, {self.views_per_scene}")
        if not 1 <= self.objects[0] <= self.objects[1] <= 15:
            raise ValueError(f"objects must be (min, max) with 1 <= min <= max <= 15, got {self.objects}")
        if self.num_samples < 1 or self.per_view < 2 or self.scenes_per_chunk < 1:
            raise ValueError("num_samples, per_view (>= 2) and scenes_per_chunk must be positive")
        if not 0.0 <= self.household_share <= 1.0:
            raise ValueError(f"household_share must lie in [0, 1], got {self.household_share}")
        if not 0.0 <= self.heavy_share <= 1.0:
            raise ValueError(f"heavy_share must lie in [0, 1], got {self.heavy_share}")
        draw_sensor(self.sensor_mix, np.random.default_rng(0))  # ValueError for an unknown sensor

    def object_parts(self) -> dict[str, list[int]]:
        """The training objects split into parts (seeded); held-out objects are never listed.  With
        household_share > 0 the training household models (ids household.HOUSEHOLD_ID_BASE + k) are split
        alike and listed after the random_urdfs."""
        ids = np.array(USABLE_TRAINING_URDFS, np.int64)
        parts = self._split(ids, np.random.default_rng([self.seed, 11]))
        if self.household_share > 0.0:
            house = np.array([household.household_id(n) for n in household.training_names()], np.int64)
            for part, members in self._split(house, np.random.default_rng([self.seed, 18])).items():
                parts[part] = parts[part] + members
        return parts

    def _split(self, ids: NDArray[np.int64], rng: np.random.Generator) -> dict[str, list[int]]:
        ids = ids[rng.permutation(len(ids))]
        n_test = int(round(self.part_fractions[0] * len(ids)))
        n_val = int(round(self.part_fractions[1] * len(ids)))
        return {"test": sorted(ids[:n_test].tolist()), "val": sorted(ids[n_test : n_test + n_val].tolist()),
                "train": sorted(ids[n_test + n_val :].tolist())}

    def scene_part(self, scene_id: int) -> str:
        """Which object part a scene draws from (deterministic; the parts' shares follow part_fractions)."""
        u = np.random.default_rng([self.seed, 12, scene_id]).random()
        return "test" if u < self.part_fractions[0] else "val" if u < sum(self.part_fractions) else "train"

    def to_dict(self) -> dict[str, Any]:
        """The parameters as JSON-able values; slip_labels and heavy_share only when set, so earlier datasets'
        params.json still match their parameters (and resume)."""
        d = asdict(self)
        d["hand"] = self.hand.to_dict()
        if not self.slip_labels:
            del d["slip_labels"]
        if not self.heavy_share:
            del d["heavy_share"]
        return d


def _choice(mix: tuple[tuple[str, float], ...], rng: np.random.Generator) -> str:
    names = [n for n, _ in mix]
    weights = np.array([w for _, w in mix], np.float64)
    return str(names[int(rng.choice(len(names), p=weights / weights.sum()))])


@dataclass
class SceneView:
    """One view of a scene: the cloud as the service receives it, the request's workspace, the ground
    truth (every mesh, which are objects) and how it was made."""

    cloud: Any
    workspace: tuple[float, float, float, float, float, float]
    truth: MeshScene
    graspable: NDArray[np.bool_]
    kind: str
    sensing: str
    num_objects: int


def scene_views(kind: str, object_ids: list[int], seed: int, views: int, hand: HandGeometry,
                noise: DepthNoise | SensorNoise, sensing_mix: tuple[tuple[str, float], ...] = SENSING_MIX,
                held_out_ok: bool = False) -> list[SceneView]:
    """Build a scene of the objects (pybullet, settled) and see it `views` times, removing one random object
    between views (never the last).  The benchmark builds the same scenes from held-out objects
    (held_out_ok, evaluation only); training never does."""
    world = _scene_world(kind, object_ids, seed, hand, held_out_ok)
    try:
        return list(_views_of(world, kind, seed, views, noise, sensing_mix))
    finally:
        world.close()


def _scene_world(kind: str, object_ids: list[int], seed: int, hand: HandGeometry, held_out_ok: bool = False
                 ) -> Any:
    """The settled pybullet world (graspd_lab.sim.world.SimWorld) of scene_views; the caller closes it.
    ValueError for a held-out object or container style (unless held_out_ok) or a scene that cannot be built."""
    from graspd_lab.sim.world import build_scene  # noqa: PLC0415 - pybullet is the lab distribution graspd-lab

    if not held_out_ok:
        for oid in object_ids:
            check_not_held_out(int(oid))
    scene_kind = "pile" if kind == "single" else kind
    container = None
    if kind.startswith("container:"):
        from graspd_lab.sim.containers import TRAINING_STYLES, sample_container  # noqa: PLC0415 - beside build_scene
        style = kind.split(":", 1)[1]
        if style not in TRAINING_STYLES and not held_out_ok:
            raise ValueError(f"container style {style!r} is held out of training (graspd_lab.sim.containers)")
        container = sample_container(style, np.random.default_rng([seed, 22]), "training")
        scene_kind = "container"
    return build_scene(scene_kind, len(object_ids), seed, hand, object_ids=tuple(int(i) for i in object_ids),
                       container=container)


def _views_of(world: Any, kind: str, seed: int, views: int, noise: DepthNoise | SensorNoise,
              sensing_mix: tuple[tuple[str, float], ...]) -> Iterator[SceneView]:
    """scene_views' views of an open world, one at a time: the world stays as the view saw it until the next is
    asked for (a physics labeller lifts grasps in it meanwhile, restoring it)."""
    from graspd_lab.sim.sensing import observe  # noqa: PLC0415 - pybullet

    rng = np.random.default_rng([seed, 13])
    region = world.workspace()
    for v in range(views):
        if not world.objects:
            break
        if v > 0 and len(world.objects) > 1:
            world.remove_object(int(rng.choice(sorted(world.objects))))
            world.settle(1.0)
            world.remove_outside()
            if not world.objects:
                break
        sensing = _choice(sensing_mix, rng)
        cloud = observe(world.client, sensing_cameras(sensing), noise, rng, region)
        static = world.static_meshes()
        posed = [m for _, m in world.object_meshes()]
        graspable = np.r_[np.zeros(len(static), bool), np.ones(len(posed), bool)]
        yield SceneView(cloud=cloud, workspace=region, truth=MeshScene(static + posed), graspable=graspable,
                        kind=kind, sensing=sensing, num_objects=len(posed))


def _view_rows(view: SceneView, scene_id: int, view_id: int, params: SceneParams, rng: np.random.Generator,
               world: Any = None) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """Labelled rows of one view (all candidates the detector would score, capped at per_view) and its record.
    world: the open pybullet world the view saw (graspd_lab.sim.world.SimWorld); given, the kept positives are
    lifted in it (graspd_lab.sim.lift.lift_labels) and those that do not hold become 0 (the record counts how
    they ended: "lifts")."""
    record: dict[str, Any] = {"object_id": scene_id, "view_id": view_id, "sensing": view.sensing,
                              "num_objects": view.num_objects, "num_points": len(view.cloud), "num_candidates": 0,
                              "num_positive": 0, "num_negative": 0, "kept": 0}
    if len(view.cloud) < 50:
        return _empty_rows(), record
    det = GraspDetector(None, params.hand)
    p = DetectionParams(num_samples=params.num_samples, workspace=view.workspace, seed=int(rng.integers(2**31)))
    prep = det.prepare(view.cloud, p, params.hand)
    cands, region = det.search(prep, prep.sampling, p, params.hand)
    record["num_candidates"] = len(cands)
    if len(cands) == 0:
        return _empty_rows(), record
    if params.hard_negatives_per_view > 0:
        cands, region = _with_hard_candidates(det, prep, cands, region, p, params, rng)
    lab = label_grasps(view.truth, cands, params.hand, params.labels, graspable=view.graspable)
    pos, neg = np.flatnonzero(lab.grasp), np.flatnonzero(~lab.grasp)
    record.update(num_positive=len(pos), num_negative=len(neg))
    k_pos = min(len(pos), params.per_view // 2)
    k_neg = min(len(neg), params.per_view - k_pos, max(params.negatives_per_positive * k_pos, params.min_negatives))
    mask = np.zeros(len(cands), bool)
    mask[rng.choice(pos, k_pos, replace=False)] = True
    mask[rng.choice(neg, k_neg, replace=False)] = True
    keep = np.flatnonzero(mask)
    chosen: GraspSet = cands[mask]
    images = encode_images(prep.scene, chosen, params.hand, STORED_REPRESENTATION, region=region.subset(mask))
    record["kept"] = len(keep)
    n = len(keep)
    labels = lab.grasp[keep].astype(np.uint8)
    if world is not None:
        from graspd_lab.sim.lift import lift_labels  # noqa: PLC0415 - pybullet

        positive = np.flatnonzero(labels)
        with world.replica() as copy:  # the scene's own world goes on to its next view untouched
            lifted = lift_labels(copy, chosen[positive], params.hand)
        labels[positive[~lifted.held]] = 0
        record["lifts"] = lifted.counts()
    rows: dict[str, NDArray[Any]] = {
        "images": images,
        "labels": labels,
        "object_ids": np.full(n, scene_id, np.int32),
        "view_ids": np.full(n, view_id, np.int32),
        "categories": np.full(n, 2, np.uint8),  # "other": scene rows carry no object category
        "positions": chosen.positions.astype(np.float32),
        "rotations": chosen.rotations.astype(np.float32),
        "widths": chosen.widths.astype(np.float32),
    }
    return rows, record


def _with_hard_candidates(det: GraspDetector, prep: Any, cands: GraspSet, region: ClosingRegionPoints,
                          p: DetectionParams, params: SceneParams, rng: np.random.Generator
                          ) -> tuple[GraspSet, ClosingRegionPoints]:
    """The detector's candidates plus up to hard_negatives_per_view of the hands it rejects: searched with no
    environment model and unseen space allowed (pinches of rims and walls, grasps on the support, hands in
    unseen space), labelled like the rest, so the classifier learns them too."""
    loose = replace(p, environment=EnvironmentParams(mode="none"), unknown_space="allow")
    sampling = replace(prep.sampling, sample_pool=None, obstacles=None, support=None, clear_behind=None)
    extra, extra_region = det.search(replace(prep, environment=Environment.empty(len(prep.cloud))), sampling,
                                     loose, params.hand)
    if len(extra) == 0:
        return cands, region
    # hands the default search did not return: not within 5 mm and 10 degrees of one of its candidates
    fresh = np.ones(len(extra), bool)
    if len(cands):
        tree = cKDTree(cands.positions)
        near = tree.query_ball_point(extra.positions, 0.005)
        for i, js in enumerate(near):
            if js and (np.abs(np.einsum("j,kj->k", extra.approach[i], cands.approach[js])) > 0.985).any():
                fresh[i] = False
    idx = np.flatnonzero(fresh)
    idx = idx[rng.permutation(len(idx))[: params.hard_negatives_per_view]]
    keep = np.zeros(len(extra), bool)
    keep[idx] = True
    hard, hard_region = extra[keep], extra_region.subset(keep)
    joined = ClosingRegionPoints(np.concatenate([region.grasp, hard_region.grasp + len(cands)]),
                                 np.concatenate([region.local, hard_region.local]),
                                 np.concatenate([region.index, hard_region.index]))
    return GraspSet.concatenate([cands, hard]), joined


def scene_spec(scene_id: int, params: SceneParams, parts: dict[str, list[int]]) -> dict[str, Any]:
    """What scene scene_id is: kind, part, object ids and sensor (deterministic from the seed)."""
    rng = np.random.default_rng([params.seed, 14, scene_id])
    kind = _choice(params.scene_mix, rng)
    part = params.scene_part(scene_id)
    n = 1 if kind == "single" else int(rng.integers(params.objects[0], params.objects[1] + 1))
    pool = np.asarray(parts[part])
    house = np.zeros(len(pool), bool)
    n_house = 0
    if params.household_share > 0.0:
        house = pool >= household.HOUSEHOLD_ID_BASE
        n_house = min(int(np.random.default_rng([params.seed, 18, scene_id]).binomial(n, params.household_share)),
                      int(house.sum()))
    ids = rng.choice(pool[~house], size=n - n_house, replace=False)
    if n_house and params.heavy_share > 0.0:
        ids = np.r_[ids, _household_draw(pool[house], n_house, params.heavy_share,
                                         np.random.default_rng([params.seed, 21, scene_id]))]
    elif n_house:
        ids = np.r_[ids, np.random.default_rng([params.seed, 19, scene_id]).choice(pool[house], size=n_house,
                                                                                   replace=False)]
    sensor = draw_sensor(params.sensor_mix, np.random.default_rng([params.seed, 20, scene_id]))
    return {"id": scene_id, "name": f"scene_{scene_id:05d}", "source": kind, "category": "other", "part": part,
            "objects": [int(i) for i in ids], "sensor": sensor}


def _household_draw(pool: NDArray[np.int64], n: int, heavy_share: float, rng: np.random.Generator
                    ) -> NDArray[np.int64]:
    """n distinct household ids of pool, each heavy (household.heavy_training_names) with probability heavy_share
    as far as the pool's heavy and light models go."""
    heavy_ids = {household.household_id(name) for name in household.heavy_training_names()}
    is_heavy = np.array([int(i) in heavy_ids for i in pool], bool)
    n_heavy = min(int(rng.binomial(n, heavy_share)), int(is_heavy.sum()))
    n_heavy = max(n_heavy, n - int((~is_heavy).sum()))  # too few light ones: more heavy
    return np.r_[rng.choice(pool[is_heavy], size=n_heavy, replace=False),
                 rng.choice(pool[~is_heavy], size=n - n_heavy, replace=False)].astype(np.int64)


def scene_noise(spec: dict[str, Any], params: SceneParams) -> DepthNoise | SensorNoise:
    """The noise model a scene is seen with: params.noise for the Kinect, else the sensor's default model."""
    sensor = spec.get("sensor", "kinect")
    return params.noise if sensor == "kinect" else sensor_noise(sensor)


def _generate_chunk(task: tuple[int, list[dict[str, Any]], SceneParams, str]
                    ) -> tuple[int, list[dict[str, Any]], list[dict[str, Any]], dict[str, Any]]:
    """Worker: every view of a group of scenes -> one chunk file (skipped if already written: resumable)."""
    chunk_index, specs, params, out_dir = task
    name = f"chunk_{chunk_index:05d}.npz"
    done = Path(out_dir) / f"{name}.json"
    if done.exists():  # written by an earlier, interrupted run
        saved = json.loads(done.read_text())
        return chunk_index, saved["scenes"], saved["views"], saved["entry"]
    views, parts = [], []
    scenes = []
    for spec in specs:
        rng = np.random.default_rng([params.seed, 15, spec["id"]])
        seed = params.seed * 100_003 + spec["id"]
        try:
            world = _scene_world(spec["source"], spec["objects"], seed, params.hand)
        except ValueError as exc:
            scenes.append({**spec, "skipped": str(exc)})
            continue
        scenes.append(spec)
        try:  # each view is labelled while the world is as it saw it (the lifts need it)
            seen = _views_of(world, spec["source"], seed, params.views_per_scene, scene_noise(spec, params),
                             params.sensing_mix)
            for view_id, view in enumerate(seen):
                rows, record = _view_rows(view, spec["id"], view_id, params, rng,
                                          world if params.slip_labels else None)
                views.append({**record, "sensor": spec.get("sensor", "kinect")})
                parts.append(rows)
        finally:
            world.close()
    arrays = {k: np.concatenate([p[k] for p in [_empty_rows(), *parts]]) for k in CHUNK_KEYS}
    digest = write_npz(Path(out_dir) / name, arrays)
    labels = arrays["labels"]
    entry = {"file": name, "rows": int(len(labels)), "positive": int(labels.sum()), "sha256": digest}
    done.write_text(json.dumps({"scenes": scenes, "views": views, "entry": entry}))
    return chunk_index, scenes, views, entry


def _splits(scenes: list[dict[str, Any]], views: list[dict[str, Any]], params: SceneParams
            ) -> tuple[dict[str, Any], dict[str, Any]]:
    """Object split: scenes by the part their objects come from.  View split: the training-part scenes'
    views divided (seeded) into train/val/test, so the view split's test part has seen objects in new scenes
    and arrangements; the object split's test part has only unseen objects."""
    obj: dict[str, Any] = {"kind": "object", "train": [], "val": [], "test": []}
    for s in scenes:
        if "skipped" not in s:
            obj[s["part"]].append(int(s["id"]))
    view: dict[str, Any] = {"kind": "view", "train": [], "val": [], "test": []}
    train_scenes = set(obj["train"])
    f_test, f_val = params.part_fractions
    for v in views:
        if v["object_id"] not in train_scenes:
            continue
        u = np.random.default_rng([params.seed, 16, v["object_id"], v["view_id"]]).random()
        part = "test" if u < f_test else "val" if u < f_test + f_val else "train"
        view[part].append([int(v["object_id"]), int(v["view_id"])])
    for part in PARTS:
        obj[part] = sorted(obj[part])
        view[part] = sorted(view[part])
    return view, obj


def generate_scene_dataset(out_dir: str | Path, params: SceneParams, workers: int = 2, progress: bool = False,
                           runner: Runner | None = None) -> dict[str, Any]:
    """Write a scene dataset to out_dir and return its manifest; rerunning the same command after an
    interruption keeps the chunks already written (each chunk's record sits beside it).  runner: how the
    chunks run (graspd_lab.cluster: serial, a pool, Ray tasks); default: a spawn pool of `workers`."""
    runner = runner or Runner(workers=max(1, workers), context="spawn")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / "manifest.json").exists():
        raise FileExistsError(f"{out} already holds a finished dataset; choose an empty --out folder")
    saved = out / "params.json"
    if saved.exists() and json.loads(saved.read_text()) != json.loads(json.dumps(params.to_dict())):
        raise FileExistsError(f"{out} holds chunks of a run with other parameters; choose an empty --out folder")
    saved.write_text(json.dumps(params.to_dict(), indent=1))
    parts = params.object_parts()
    specs = [scene_spec(s, params, parts) for s in range(params.scenes)]
    g = params.scenes_per_chunk
    tasks = [(c, specs[a : a + g], params, str(out)) for c, a in enumerate(range(0, len(specs), g))]
    t0 = time.perf_counter()
    results = _collect(imap(_generate_chunk, tasks, runner), len(tasks), t0, progress)
    results.sort(key=lambda r: r[0])
    missing = [r[3]["file"] for r in results if not (out / r[3]["file"]).is_file()]
    if missing:  # Ray workers on other nodes wrote them into a folder of their own
        raise FileNotFoundError(f"chunks {missing[:3]} were written elsewhere: on a Ray cluster --out must be a "
                                "folder every node sees (a shared file system)")
    scenes = [s for r in results for s in r[1]]
    views = [v for r in results for v in r[2]]
    chunks = [r[3] for r in results]
    view_split, obj_split = _splits(scenes, views, params)
    (out / "splits").mkdir(exist_ok=True)
    (out / "splits" / "view.json").write_text(json.dumps(view_split))
    (out / "splits" / "object.json").write_text(json.dumps(obj_split))
    total = sum(c["rows"] for c in chunks)
    positive = sum(c["positive"] for c in chunks)
    manifest: dict[str, Any] = {
        "format": FORMAT, "kind": "scenes", "seed": params.seed, "representation": STORED_REPRESENTATION,
        "derivable": list(DERIVABLE), "image_size": 60, "channels": channel_layout(STORED_REPRESENTATION),
        "hand": params.hand.to_dict(), "parameters": params.to_dict(), "object_parts": parts,
        "objects": scenes, "views": views, "chunks": chunks,
        "counts": {"total": total, "positive": positive, "negative": total - positive,
                   "by_category": {"other": total}, "target": params.scenes * params.views_per_scene * params.per_view},
        "dataset_sha256": chunks_sha256(chunks),
        "command": "python -m graspd_lab.training.scene_data " + " ".join(sys.argv[1:]),
    }
    (out / "manifest.json").write_text(json.dumps(manifest))
    seconds = time.perf_counter() - t0
    (out / "timing.json").write_text(json.dumps({"seconds": seconds, "workers": runner.workers,
                                                 "runner": runner.describe(),
                                                 "exemplars_per_minute": 60.0 * total / max(seconds, 1e-9)}))
    return manifest


def hand_with_opening(preset: str, opening: float | None) -> HandGeometry:
    """A named hand, its opening (m) replaced when given: the outer faces move, the fingers stay as they are."""
    hand = hand_preset(preset)
    if opening is None:
        return hand
    if not 0.0 < opening <= 0.3:
        raise ValueError(f"--hand-opening must be in (0, 0.3] m, got {opening}")
    return hand.with_opening(opening)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m graspd_lab.training.scene_data",
                                 description="Generate labelled grasp images from cluttered scenes (see module doc).")
    ap.add_argument("--out", required=True, help="output folder (rerun the same command to resume)")
    ap.add_argument("--scenes", type=int, default=600)
    ap.add_argument("--views", type=int, default=4, help="views per scene (one object removed between views)")
    ap.add_argument("--samples", type=int, default=150, help="detector num_samples per view")
    ap.add_argument("--per-view", type=int, default=160, help="most rows kept per view")
    ap.add_argument("--objects", type=int, nargs=2, default=(4, 10), metavar=("MIN", "MAX"))
    ap.add_argument("--hand", default="gpd", help=f"hand preset: {sorted(HAND_PRESETS)}")
    ap.add_argument("--hand-opening", type=float, default=None, metavar="M",
                    help="the preset's opening between the fingers replaced by this one (m): e.g. --hand panda "
                    "--hand-opening 0.075 is the household benchmarks' Panda-like hand")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2, help="processes (or Ray CPUs with --ray)")
    add_cluster_arguments(ap)
    ap.add_argument("--scenes-per-chunk", type=int, default=10)
    ap.add_argument("--mix", choices=sorted(MIXES), default="clutter",
                    help="scene kinds: clutter (trays, piles, packed rows, lone objects) or containers (the "
                    "container family's training styles with some trays and piles)")
    ap.add_argument("--household-share", type=float, default=0.0, metavar="F",
                    help="expected share of each scene's objects that are household models at true size (0-1)")
    ap.add_argument("--heavy-share", type=float, default=0.0, metavar="F",
                    help="expected share of the household models drawn from the heavy ones (0.5 kg or more: "
                    "those that slip; 0: uniform)")
    ap.add_argument("--sensors", choices=sorted(SENSOR_MIXES), default="kinect",
                    help="the sensor each scene is seen with: kinect (the benchmark's model) or mixed (Kinect, "
                    "active stereo and ToF, drawn per scene)")
    ap.add_argument("--hard-negatives", type=int, default=0, metavar="N",
                    help="per view, add up to N hands the detector rejects (rims, walls, support, unseen space)")
    ap.add_argument("--slip-labels", action="store_true",
                    help="lift every kept positive in physics (the benchmark's hand) and label it 0 unless the "
                    "object stays in the fingers, turning at most 15 degrees (graspd_lab.sim.lift)")
    args = ap.parse_args(argv)
    try:
        params = SceneParams(seed=args.seed, scenes=args.scenes, views_per_scene=args.views,
                             objects=(args.objects[0], args.objects[1]), num_samples=args.samples,
                             per_view=args.per_view, scenes_per_chunk=args.scenes_per_chunk,
                             hand=hand_with_opening(args.hand, args.hand_opening), scene_mix=MIXES[args.mix],
                             hard_negatives_per_view=args.hard_negatives, household_share=args.household_share,
                             sensor_mix=SENSOR_MIXES[args.sensors], slip_labels=args.slip_labels,
                             heavy_share=args.heavy_share)
        runner = runner_from_args(args, args.workers, context="spawn")
    except (ValueError, KeyError, RayMissingError) as exc:
        ap.error(str(exc))
    manifest = generate_scene_dataset(args.out, params, progress=True, runner=runner)
    timing = json.loads((Path(args.out) / "timing.json").read_text())
    c = manifest["counts"]
    print(f"{c['total']} exemplars ({c['positive']} positive) from {len(manifest['objects'])} scenes in "
          f"{timing['seconds']:.0f} s, {runner.describe()}; dataset_sha256 {manifest['dataset_sha256']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["SceneParams", "SceneView", "generate_scene_dataset", "hand_with_opening", "scene_noise", "scene_spec",
           "scene_views"]
