"""A pybullet world (DIRECT mode) holding a table, a tray or container and objects, built as one of four
scene kinds.

Frame: world z up, the table (the floor) top at z = 0, the tray, container or workspace centred on the
origin.  "pour" is the IJRR protocol (objects poured from a box into a tray), "pile" and "packed" are VGN's
scenes (a 30 cm box, removed after the drop; objects standing upright), "container" drops objects into one
container of graspd_lab.sim.containers (a ContainerSpec: tray, deep bin, thin box, corner, platform, shelf,
tote; any yaw) standing on the table.  Every static body is a box; static_boxes / static_meshes /
static_labels give them exactly (pose and extents), for labels and tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d
import pybullet as pb

from graspd.core.hand import HandGeometry
from graspd_lab.sim.containers import ContainerSpec
from graspd_lab.sim.objects import TEST_OBJECT_IDS, body_mesh, graspable_scale, load_flags, object_urdf
from graspd_lab.world.scenes import TrayGeometry

SCENE_KINDS = ("pour", "pile", "packed", "container")
TIME_STEP = 1.0 / 240.0
#: Constraint solver iterations per 1/240 s step: the standard clutter-removal benchmark's simulator (VGN) runs
#: 150.  pybullet's default (50) leaves light objects (a 5-50 g packet) squeezed by 40 N fingers unconverged: they
#: squirt out of a closed hand, a failure no real hand has.  At 150 a 5 g rod of 8-12 mm still does (from 250 up it
#: holds); 300 was tried and moved the benchmarks both ways (bench/results/*-solver300.md), so the standard's value
#: stays.
SOLVER_ITERATIONS = 150


def _connect() -> int:
    """A new DIRECT physics client with gravity, the time step and the solver iterations every world uses."""
    client = pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    pb.setPhysicsEngineParameter(fixedTimeStep=TIME_STEP, numSolverIterations=SOLVER_ITERATIONS,
                                 physicsClientId=client)
    return client


@dataclass
class SimWorld:
    """One physics client with the table, optional tray walls or a container, and the objects still in play."""

    client: int
    tray: TrayGeometry
    has_tray: bool
    objects: dict[int, int] = field(default_factory=dict)  # body id -> random_urdfs object id
    static_bodies: list[int] = field(default_factory=list)
    scales: dict[int, float] = field(default_factory=dict)  # body id -> globalScaling
    container: ContainerSpec | None = None
    static_names: dict[int, str] = field(default_factory=dict)  # body id -> "table", "wall", "floor", "wall+x", ...

    @staticmethod
    def create(tray: TrayGeometry | None = None, has_tray: bool = True,
               container: ContainerSpec | None = None) -> SimWorld:
        """A world with the table (a 10 m box whose top is z = 0) and either the tray's walls (has_tray) or
        the container's floor slab, walls and ceiling (container; then has_tray must be False)."""
        if container is not None and has_tray:
            raise ValueError("a world holds either the tray (has_tray) or a container, not both")
        client = _connect()
        world = SimWorld(client=client, tray=tray or TrayGeometry(), has_tray=has_tray, container=container)
        floor = world._box([5.0, 5.0, 0.01], [0.0, 0.0, -0.01], rgba=(0.55, 0.5, 0.45, 1))
        world._add_static(floor, "table")
        if has_tray:
            for wall in world._walls(world.tray.size_x, world.tray.size_y):
                world._add_static(wall, "wall")
        if container is not None:
            for box in container.boxes():
                rgba = (0.35, 0.45, 0.6, 1) if box.name.startswith("wall") else (0.45, 0.55, 0.5, 1)
                world._add_static(world._box(list(box.half), list(box.centre), rgba=rgba, yaw=box.yaw), box.name)
        return world

    def replica(self) -> SimWorld:
        """A second physics client with this world's static boxes (names, poses, extents) and objects (ids, scales,
        poses, velocities) as they are now: grasps tried in it leave this world, and every later step of it,
        exactly as they would have been (adding and removing a hand here would not).  Close it after."""
        client = _connect()
        copy = SimWorld(client=client, tray=self.tray, has_tray=self.has_tray, container=self.container)
        for name, centre, rot, half in self.static_boxes():
            yaw = float(np.arctan2(rot[1, 0], rot[0, 0]))  # static boxes turn about z only
            copy._add_static(copy._box(half.tolist(), centre.tolist(), yaw=yaw), name)
        for body, object_id in self.objects.items():
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
            new = copy.add_object(object_id, np.asarray(pos), np.asarray(quat), self.scales.get(body, 1.0))
            # loadURDF places the link frame, the base pose is the inertial frame's: set it as read
            pb.resetBasePositionAndOrientation(new, pos, quat, physicsClientId=client)
            linear, angular = pb.getBaseVelocity(body, physicsClientId=self.client)
            pb.resetBaseVelocity(new, linear, angular, physicsClientId=client)
        return copy

    def _add_static(self, body: int, name: str) -> None:
        self.static_bodies.append(body)
        self.static_names[body] = name

    def close(self) -> None:
        if pb.isConnected(self.client):
            pb.disconnect(self.client)

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- building ---------------------------------------------------------------------------------
    def _box(self, half: list[float], pos: list[float], rgba: tuple[float, ...] = (0.4, 0.4, 0.45, 1),
             mass: float = 0.0, yaw: float = 0.0) -> int:
        """A box body of half extents half (m) centred at pos (world, m), turned by yaw (rad) about z."""
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=self.client)
        quat = pb.getQuaternionFromEuler([0.0, 0.0, yaw])
        body = pb.createMultiBody(mass, col, vis, pos, quat, physicsClientId=self.client)
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
                           globalScaling=scale, flags=load_flags(object_id), physicsClientId=self.client)
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

    def static_boxes(self) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
        """Every static body (the order of static_bodies) as (name, centre (3,) world m, rotation (3, 3)
        box-to-world, half extents (3,) m), read from pybullet's pose and collision shape."""
        out = []
        for body in self.static_bodies:
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
            rot = np.asarray(pb.getMatrixFromQuaternion(quat), np.float64).reshape(3, 3)
            dims = np.asarray(pb.getCollisionShapeData(body, -1, physicsClientId=self.client)[0][3], np.float64)
            out.append((self.static_names.get(body, "static"), np.asarray(pos, np.float64), rot, dims / 2))
        return out

    def static_meshes(self) -> list[o3d.geometry.TriangleMesh]:
        """The table, tray walls or the container's floor slab, walls and ceiling as world-frame box meshes
        (m), posed exactly (yaw included): what holds the objects.  Same order as static_bodies."""
        out = []
        for _, centre, rot, half in self.static_boxes():
            box = o3d.geometry.TriangleMesh.create_box(*(2 * half))
            box.translate(-half)
            box.rotate(rot, center=np.zeros(3))
            box.translate(centre)
            box.compute_triangle_normals()
            out.append(box)
        return out

    def static_labels(self, points: np.ndarray, tol: float = 0.004) -> np.ndarray:
        """For world points (N, 3), the index (into static_bodies / static_meshes) of the static box each lies
        in or within tol (m) of, the nearest when several; -1 for points on no static body (objects, air).
        A negative tol asks for points at least -tol inside a box (a hand that enters it)."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        boxes = self.static_boxes()
        if not boxes or len(pts) == 0:
            return np.full(len(pts), -1, np.int64)
        dist = np.empty((len(boxes), len(pts)))
        for k, (_, centre, rot, half) in enumerate(boxes):
            local = (pts - centre) @ rot
            dist[k] = np.max(np.abs(local) - half, axis=1)  # <= 0 inside; the largest axis overshoot outside
        best = np.argmin(dist, axis=0)
        return np.where(dist[best, np.arange(len(pts))] <= tol, best, -1).astype(np.int64)

    def in_play(self, points: np.ndarray) -> np.ndarray:
        """Which world positions (N, 3) count as still in play: above the tray's or container's interior
        (the container's tested in its own frame, yaw included) or the pile region, and -1 cm < z < 0.5 m."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        if self.container is not None:
            xy = self.container.interior_contains(p)
        else:
            x0, x1, y0, y1 = self.inside_region()
            xy = (x0 <= p[:, 0]) & (p[:, 0] <= x1) & (y0 <= p[:, 1]) & (p[:, 1] <= y1)
        return np.asarray(xy & (p[:, 2] > -0.01) & (p[:, 2] < 0.5))

    def inside_region(self) -> tuple[float, float, float, float]:
        """[xmin, xmax, ymin, ymax] (m) in which an object counts as still in play; for a container the
        axis-aligned bounds of its (turned) interior, whose exact test is in_play."""
        if self.container is not None:
            xy = self.container.interior_corners()
            lo, hi = xy.min(axis=0), xy.max(axis=0)
            return (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
        if self.has_tray:
            return self.tray.interior
        half = 0.15
        return (-half, half, -half, half)

    def workspace(self, margin: float | None = None) -> tuple[float, float, float, float, float, float]:
        """The box [xmin, xmax, ymin, ymax, zmin, zmax] (m) the cameras keep and a robot sends as its workspace:
        the play region plus margin (default 2 cm), floor and tray walls included, up to 0.4 m; for a container
        its footprint (walls included, any yaw) plus margin (default 5 cm of table around it)."""
        if self.container is not None:
            return self.container.workspace() if margin is None else self.container.workspace(margin)
        m = 0.02 if margin is None else margin
        x0, x1, y0, y1 = self.inside_region()
        return (x0 - m, x1 + m, y0 - m, y1 + m, -0.005, 0.4)

    def remove_outside(self) -> list[int]:
        """Remove objects whose centre left the tray, container or workspace (or fell below the floor); their
        ids."""
        gone = []
        for body in list(self.objects):
            if not self.in_play(self.object_position(body))[0]:
                gone.append(self.objects[body])
                self.remove_object(body)
        return gone


def random_quat(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion (x, y, z, w)."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def build_scene(kind: str, num_objects: int, seed: int, hand: HandGeometry,
                object_ids: tuple[int, ...] = TEST_OBJECT_IDS, container: ContainerSpec | None = None) -> SimWorld:
    """A settled world of the given kind with num_objects distinct objects of object_ids (default: the held-out
    test objects) drawn by seed.  kind "container" needs container (graspd_lab.sim.containers.sample_container or
    scene_container): the objects are dropped into its interior; objects that end outside it are removed."""
    if kind not in SCENE_KINDS:
        raise ValueError(f"scene kind must be one of {SCENE_KINDS}, got {kind!r}")
    if (kind == "container") != (container is not None):
        raise ValueError("scene kind 'container' needs a container (ContainerSpec), and only it takes one")
    if not 1 <= num_objects <= len(object_ids):
        raise ValueError(f"num_objects must be in [1, {len(object_ids)}], got {num_objects}")
    rng = np.random.default_rng(seed)
    chosen = rng.choice(np.asarray(object_ids), size=num_objects, replace=False)
    world = SimWorld.create(has_tray=(kind == "pour"), container=container)
    if kind == "pour":
        _pour(world, chosen, rng, hand)
    elif kind == "pile":
        _pile(world, chosen, rng, hand)
    elif kind == "container":
        _drop_into(world, chosen, rng, hand)
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


def _drop_into(world: SimWorld, chosen: np.ndarray, rng: np.random.Generator, hand: HandGeometry) -> None:
    """Objects fall one after another from above random points of the container's interior and settle
    (the pour's drop, VGN pile's guides): open sides (platform, corner, shelf front) get temporary walls on
    the table at the interior's edge, lifted away once everything rests; then the scene settles again."""
    spec = world.container
    assert spec is not None
    hx, hy = spec.inner_x / 2, spec.inner_y / 2
    guide_top = spec.wall_top + 0.25 if not spec.ceiling_height else spec.ceiling_height
    guides = []
    g = 0.01  # guide thickness (m)
    for side in spec.open_sides():
        sign = -1.0 if side[0] == "-" else 1.0
        if side[1] == "x":
            centre, half = [sign * (hx + g / 2), 0.0, guide_top / 2], [g / 2, hy + 2 * g, guide_top / 2]
        else:
            centre, half = [0.0, sign * (hy + g / 2), guide_top / 2], [hx + 2 * g, g / 2, guide_top / 2]
        c = spec.to_world(np.asarray(centre))[0]
        guides.append(world._box(half, c.tolist(), yaw=spec.yaw))
    # keep clear of the walls; on a platform, well inside its edges (objects there fall off once the guides go)
    inset = 0.3 * np.array([hx, hy]) if not spec.walls else np.minimum(0.04, 0.3 * np.array([hx, hy]))
    base = spec.wall_top + 0.07
    if spec.ceiling_height:
        base = min(base, spec.floor_height + 0.12)
    for k, oid in enumerate(chosen):
        local = np.array([rng.uniform(-hx + inset[0], hx - inset[0]), rng.uniform(-hy + inset[1], hy - inset[1]),
                          base + (0.02 * k if not spec.ceiling_height else 0.0)])
        pos = spec.to_world(local)[0]
        world.add_object(int(oid), pos, random_quat(rng), graspable_scale(int(oid), hand))
        world.step(0.25)
    world.settle()
    for body in guides:
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
