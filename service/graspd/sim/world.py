"""A pybullet world (DIRECT mode) holding a tray and test objects, built as one of three scene kinds.

Frame: world z up, the floor at z = 0, the tray or workspace centred on the origin.  "pour" is the
IJRR protocol (objects poured from a box into a tray), "pile" and "packed" are VGN's scenes (a 30 cm
box, removed after the drop; objects standing upright).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
import pybullet as pb

from ..hand import HandGeometry
from ..world.scenes import TrayGeometry
from .objects import TEST_OBJECT_IDS, body_mesh, graspable_scale, object_urdf

SCENE_KINDS = ("pour", "pile", "packed")
TIME_STEP = 1.0 / 240.0


@dataclass
class SimWorld:
    """One physics client with floor, optional tray walls and the objects still in play."""

    client: int
    tray: TrayGeometry
    has_tray: bool
    objects: dict[int, int] = field(default_factory=dict)  # body id -> random_urdfs object id
    static_bodies: list[int] = field(default_factory=list)
    scales: dict[int, float] = field(default_factory=dict)  # body id -> globalScaling

    @staticmethod
    def create(tray: TrayGeometry | None = None, has_tray: bool = True) -> SimWorld:
        client = pb.connect(pb.DIRECT)
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.setTimeStep(TIME_STEP, physicsClientId=client)
        world = SimWorld(client=client, tray=tray or TrayGeometry(), has_tray=has_tray)
        floor = world._box([5.0, 5.0, 0.01], [0.0, 0.0, -0.01], rgba=(0.55, 0.5, 0.45, 1))
        world.static_bodies.append(floor)
        if has_tray:
            world.static_bodies.extend(world._walls(world.tray.size_x, world.tray.size_y))
        return world

    def close(self) -> None:
        if pb.isConnected(self.client):
            pb.disconnect(self.client)

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- building ---------------------------------------------------------------------------------
    def _box(self, half: list[float], pos: list[float], rgba: tuple[float, ...] = (0.4, 0.4, 0.45, 1),
             mass: float = 0.0) -> int:
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=self.client)
        body = pb.createMultiBody(mass, col, vis, pos, physicsClientId=self.client)
        pb.changeDynamics(body, -1, lateralFriction=0.8, physicsClientId=self.client)
        return body

    def _walls(self, size_x: float, size_y: float, height: float | None = None) -> list[int]:
        """Four static walls around [-size_x/2, size_x/2] x [-size_y/2, size_y/2], standing on the floor."""
        h = self.tray.wall_height if height is None else height
        t = self.tray.wall_thickness
        hx, hy = size_x / 2 + t, size_y / 2 + t
        return [
            self._box([t / 2, hy, h / 2], [sx * (size_x / 2 + t / 2), 0.0, h / 2]) for sx in (-1, 1)
        ] + [self._box([hx, t / 2, h / 2], [0.0, sy * (size_y / 2 + t / 2), h / 2]) for sy in (-1, 1)]

    def add_object(self, object_id: int, position: np.ndarray, quat_xyzw: np.ndarray, scale: float) -> int:
        body = pb.loadURDF(object_urdf(object_id), position.tolist(), quat_xyzw.tolist(),
                           globalScaling=scale, physicsClientId=self.client)
        pb.changeDynamics(body, -1, lateralFriction=1.0, spinningFriction=0.002, rollingFriction=0.0005,
                          physicsClientId=self.client)
        self.objects[body] = object_id
        self.scales[body] = scale
        return body

    def remove_object(self, body: int) -> None:
        pb.removeBody(body, physicsClientId=self.client)
        self.objects.pop(body, None)
        self.scales.pop(body, None)

    def step(self, seconds: float) -> None:
        for _ in range(int(round(seconds / TIME_STEP))):
            pb.stepSimulation(physicsClientId=self.client)

    def settle(self, max_seconds: float = 3.0, speed: float = 0.01) -> None:
        """Step until every object moves slower than speed (m/s) or max_seconds have passed."""
        for _ in range(int(max_seconds / 0.1)):
            self.step(0.1)
            if all(np.linalg.norm(pb.getBaseVelocity(b, physicsClientId=self.client)[0]) < speed
                   for b in self.objects):
                return

    def object_position(self, body: int) -> np.ndarray:
        return np.asarray(pb.getBasePositionAndOrientation(body, physicsClientId=self.client)[0])

    def object_meshes(self) -> list[tuple[int, o3d.geometry.TriangleMesh]]:
        """(body id, its mesh posed in the world frame, m) of every object in play: the ground truth."""
        out = []
        for body, object_id in self.objects.items():
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
            rot = np.asarray(pb.getMatrixFromQuaternion(quat), np.float64).reshape(3, 3)
            mesh = body_mesh(object_id, self.scales.get(body, 1.0))
            mesh.rotate(rot, center=np.zeros(3))
            mesh.translate(np.asarray(pos))
            mesh.compute_triangle_normals()
            out.append((body, mesh))
        return out

    def static_meshes(self) -> list[o3d.geometry.TriangleMesh]:
        """The floor and tray walls as world-frame box meshes (m): what holds the objects."""
        out = []
        for body in self.static_bodies:
            lo, hi = (np.asarray(v, np.float64) for v in pb.getAABB(body, physicsClientId=self.client))
            box = o3d.geometry.TriangleMesh.create_box(*(hi - lo))
            box.translate(lo)
            box.compute_triangle_normals()
            out.append(box)
        return out

    def inside_region(self) -> tuple[float, float, float, float]:
        """[xmin, xmax, ymin, ymax] (m) in which an object counts as still in play."""
        if self.has_tray:
            return self.tray.interior
        half = 0.15
        return (-half, half, -half, half)

    def workspace(self, margin: float = 0.02) -> tuple[float, float, float, float, float, float]:
        """The box [xmin, xmax, ymin, ymax, zmin, zmax] (m) the cameras keep and a robot sends as its workspace:
        the play region plus margin, floor and tray walls included, up to 0.4 m."""
        x0, x1, y0, y1 = self.inside_region()
        return (x0 - margin, x1 + margin, y0 - margin, y1 + margin, -0.005, 0.4)

    def remove_outside(self) -> list[int]:
        """Remove objects whose centre left the tray or workspace (or fell below the floor); their ids."""
        x0, x1, y0, y1 = self.inside_region()
        gone = []
        for body in list(self.objects):
            p = self.object_position(body)
            if not (x0 <= p[0] <= x1 and y0 <= p[1] <= y1 and -0.01 < p[2] < 0.5):
                gone.append(self.objects[body])
                self.remove_object(body)
        return gone


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion (x, y, z, w)."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def build_scene(kind: str, num_objects: int, seed: int, hand: HandGeometry,
                object_ids: tuple[int, ...] = TEST_OBJECT_IDS) -> SimWorld:
    """A settled world of the given kind with num_objects distinct held-out objects drawn by seed."""
    if kind not in SCENE_KINDS:
        raise ValueError(f"scene kind must be one of {SCENE_KINDS}, got {kind!r}")
    if not 1 <= num_objects <= len(object_ids):
        raise ValueError(f"num_objects must be in [1, {len(object_ids)}], got {num_objects}")
    rng = np.random.default_rng(seed)
    chosen = rng.choice(np.asarray(object_ids), size=num_objects, replace=False)
    world = SimWorld.create(has_tray=(kind == "pour"))
    if kind == "pour":
        _pour(world, chosen, rng, hand)
    elif kind == "pile":
        _pile(world, chosen, rng, hand)
    else:
        _packed(world, chosen, rng, hand)
    world.remove_outside()
    return world


def _pour(world: SimWorld, chosen: np.ndarray, rng: np.random.Generator, hand: HandGeometry) -> None:
    """Objects fall one after another out of a 12 cm box held above one side of the tray (Table 1 step 4)."""
    spout = np.array([rng.uniform(-0.06, 0.06), rng.uniform(-0.04, 0.04)])
    for k, oid in enumerate(chosen):
        xy = spout + rng.uniform(-0.06, 0.06, size=2)
        pos = np.array([xy[0], xy[1], 0.15 + 0.02 * k])
        world.add_object(int(oid), pos, random_quat(rng), graspable_scale(int(oid), hand))
        world.step(0.25)
    world.settle()


def _pile(world: SimWorld, chosen: np.ndarray, rng: np.random.Generator, hand: HandGeometry) -> None:
    """VGN pile: objects dropped into a 30 cm box that is then lifted away."""
    box = world._walls(0.30, 0.30, height=0.25)
    for oid in chosen:
        pos = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.08, 0.08), rng.uniform(0.15, 0.25)])
        world.add_object(int(oid), pos, random_quat(rng), graspable_scale(int(oid), hand))
        world.step(0.3)
    world.settle()
    for body in box:
        pb.removeBody(body, physicsClientId=world.client)
    world.settle()


def _packed(world: SimWorld, chosen: np.ndarray, rng: np.random.Generator, hand: HandGeometry) -> None:
    """VGN packed: objects stand upright (longest extent vertical) at free spots of a 30 cm square."""
    placed: list[tuple[np.ndarray, float]] = []
    for oid in chosen:
        scale = graspable_scale(int(oid), hand)
        body = world.add_object(int(oid), np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0]), scale)
        lo, hi = (np.asarray(v) for v in pb.getAABB(body, physicsClientId=world.client))
        ext = hi - lo
        up = int(np.argmax(ext))
        # rotate the longest axis onto z, then a random yaw
        tilt = {0: pb.getQuaternionFromEuler([0, -np.pi / 2, 0]), 1: pb.getQuaternionFromEuler([np.pi / 2, 0, 0]),
                2: (0.0, 0.0, 0.0, 1.0)}[up]
        yaw = pb.getQuaternionFromEuler([0, 0, rng.uniform(-np.pi, np.pi)])
        quat = np.asarray(pb.multiplyTransforms([0, 0, 0], yaw, [0, 0, 0], tilt)[1])
        radius = 0.5 * float(np.sort(ext)[1])
        for _ in range(50):
            xy = rng.uniform(-0.15 + radius, 0.15 - radius, size=2)
            if all(np.linalg.norm(xy - q) > radius + r + 0.005 for q, r in placed):
                break
        else:
            world.remove_object(body)
            continue
        pb.resetBasePositionAndOrientation(body, [xy[0], xy[1], 1.0], quat.tolist(), physicsClientId=world.client)
        lo, _ = pb.getAABB(body, physicsClientId=world.client)
        pb.resetBasePositionAndOrientation(body, [xy[0], xy[1], 1.0 - lo[2] + 0.002], quat.tolist(),
                                          physicsClientId=world.client)
        placed.append((xy, radius))
    world.settle()
