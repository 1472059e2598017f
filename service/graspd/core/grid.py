"""An organised cloud's image grid (graspd.core.cloud.CloudGrid): its mixed ("flying") pixels and its normals
from image neighbours, each in one compiled pass over the (H, W) image (bands of rows in parallel).

Mixed pixels: a depth camera's pixel that straddles a depth edge returns a depth between the two surfaces (or
beyond both), so a veil of points hangs along every silhouette, in the air between object and background.  Seen
from the camera, the line from such a point to its image neighbour runs almost along the ray; on any surface
the camera can actually see it runs across the ray.  The classic veil (shadow) point test: when the angle
between the ray and the line to a neighbour is under VEIL_ANGLE_DEG, after allowing for the depth noise at that
range, the farther of the two is a veil point.  Noise grows with range squared (a structured-light or stereo
camera's depth step is about DEPTH_NOISE * range^2), so the allowance does too.

Normals: each pixel's two tangents are the differences between its image neighbours about normal_radius apart
on the surface (the step in pixels grows as the range falls), one-sided where a neighbour is missing or across a
depth edge (the same veil test), as PCL's integral-image / neighbouring-pixel estimators do; the normal is their
cross product, turned toward the camera.  No neighbour search: an image row is the neighbourhood.

The per-pixel loops are compiled (graspd.core.jit): the same tests as whole-image numpy took 0.8 s on the 640x480
Kinect capture, these passes take about 30 ms (bench/grid_normals.py times the whole preprocessing)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from graspd.core.cloud import CloudGrid
from graspd.core.jit import kernel
from graspd.core.parallel import THREADS

#: The veil test's angle (degrees) between a pixel's ray and the line to its image neighbour: under it the pair
#: lies along the ray, which a visible surface does not (one seen this obliquely is a mixed-pixel veil or too
#: oblique to measure).  ROS's scan shadow filter and PCL's shadow-point filter use 10-15 degrees.
VEIL_ANGLE_DEG = 10.0
#: Depth noise (m) of a depth camera per squared metre of range: the Kinect's disparity step is 2.9e-3 r^2,
#: RealSense D4xx and textured-light stereo are 1-3e-3 r^2 (m, r in m).  The larger bound is used.
DEPTH_NOISE = 3e-3
#: How many noise steps a depth difference must exceed, besides the angle, to be a veil.
NOISE_STEPS = 3.0
#: Largest step (pixels) between the neighbours a grid normal is taken from.
MAX_NORMAL_STEP = 32
#: Image rows one task of the veil and normal passes takes (tasks run on the process's thread budget).
ROWS_PER_TASK = 64
#: Every how many rows the pixel pitch is sampled (a median: a few thousand pairs are plenty).
PITCH_ROW_STRIDE = 8
_COT = float(1.0 / np.tan(np.radians(VEIL_ANGLE_DEG)))


@kernel
def _fill(points: NDArray[np.float32], source: NDArray[np.int32], cams: NDArray[np.float32],
          pixel: NDArray[np.int64], keep: NDArray[np.bool_], width: int, ray: NDArray[np.float32],
          rng: NDArray[np.float32]) -> None:
    """ray[v, u] = the point minus its camera (m), rng[v, u] = its length, at each kept point's pixel (keep of
    length 0: all points); the other pixels stay as they are (NaN)."""
    use_keep = keep.shape[0] == points.shape[0]
    for i in range(points.shape[0]):
        if use_keep and not keep[i]:
            continue
        c = source[i]
        v, u = pixel[i] // width, pixel[i] % width
        x = np.float64(points[i, 0]) - np.float64(cams[c, 0])
        y = np.float64(points[i, 1]) - np.float64(cams[c, 1])
        z = np.float64(points[i, 2]) - np.float64(cams[c, 2])
        ray[v, u, 0], ray[v, u, 1], ray[v, u, 2] = x, y, z
        rng[v, u] = np.sqrt(x * x + y * y + z * z)


@kernel
def _is_veil(ax: float, ay: float, az: float, bx: float, by: float, bz: float, ra: float, rb: float,
             cot: float) -> bool:
    """Whether the rays a, b (m) of neighbouring pixels (ranges ra, rb) are a veil pair: their depth difference
    along the ray exceeds what a surface at VEIL_ANGLE_DEG (cot: its cotangent) to the ray spans over their
    lateral spacing, plus NOISE_STEPS depth-noise steps at the nearer range.  False when either is missing."""
    if not (np.isfinite(ra) and np.isfinite(rb)):
        return False
    dx, dy, dz = bx - ax, by - ay, bz - az
    mx, my, mz = ax + bx, ay + by, az + bz
    m = np.sqrt(mx * mx + my * my + mz * mz)
    if m == 0.0:
        return False
    radial = abs(dx * mx + dy * my + dz * mz) / m
    lateral = np.sqrt(max(dx * dx + dy * dy + dz * dz - radial * radial, 0.0))
    near = min(ra, rb)
    return radial > lateral * cot + NOISE_STEPS * DEPTH_NOISE * near * near


@kernel
def _veil_pass(ray: NDArray[np.float32], rng: NDArray[np.float32], cot: float, v0: int, v1: int,
               drop: NDArray[np.bool_]) -> None:
    """drop[v, u] for rows v0 <= v < v1 = the pixel is farther than one of its 8 neighbours it forms a veil pair
    with (_is_veil; of a pair at equal range, the later in row-major order).  Each pixel writes only its own
    flag: bands of rows run in parallel."""
    h, w = rng.shape
    for v in range(v0, v1):
        for u in range(w):
            ra = np.float64(rng[v, u])
            if not np.isfinite(ra):
                continue
            ax, ay, az = np.float64(ray[v, u, 0]), np.float64(ray[v, u, 1]), np.float64(ray[v, u, 2])
            found = False
            for q in range(max(0, v - 1), min(h, v + 2)):
                for p in range(max(0, u - 1), min(w, u + 2)):
                    if found or (q == v and p == u):
                        continue
                    rb = np.float64(rng[q, p])
                    if rb > ra or (rb == ra and (q > v or (q == v and p > u))):
                        continue  # the neighbour is the farther one (or the later at a tie): its own test
                    found = _is_veil(ax, ay, az, np.float64(ray[q, p, 0]), np.float64(ray[q, p, 1]),
                                     np.float64(ray[q, p, 2]), ra, rb, cot)
            drop[v, u] = found


@kernel
def _pitch_samples(ray: NDArray[np.float32], rng: NDArray[np.float32], cot: float, out: NDArray[np.float64]
                   ) -> int:
    """out[:count] = spacing / nearer range of horizontal neighbours that are no veil pair; returns count."""
    h, w = rng.shape
    count = 0
    for v in range(h):
        for u in range(w - 1):
            ra, rb = np.float64(rng[v, u]), np.float64(rng[v, u + 1])
            if not (np.isfinite(ra) and np.isfinite(rb)):
                continue
            ax, ay, az = np.float64(ray[v, u, 0]), np.float64(ray[v, u, 1]), np.float64(ray[v, u, 2])
            bx, by, bz = np.float64(ray[v, u + 1, 0]), np.float64(ray[v, u + 1, 1]), np.float64(ray[v, u + 1, 2])
            if _is_veil(ax, ay, az, bx, by, bz, ra, rb, cot):
                continue
            dx, dy, dz = bx - ax, by - ay, bz - az
            out[count] = np.sqrt(dx * dx + dy * dy + dz * dz) / min(ra, rb)
            count += 1
    return count


@kernel
def _usable(rng: NDArray[np.float32], r: float, q: int, p: int, allowed: float) -> bool:
    """Whether pixel (q, p) is inside the image, has a point, and its range differs from r by at most allowed
    (m: no depth edge between them; NaN compares False)."""
    h, w = rng.shape
    if q < 0 or q >= h or p < 0 or p >= w:
        return False
    return bool(abs(np.float64(rng[q, p]) - r) <= allowed)


@kernel
def _normals_pass(ray: NDArray[np.float32], rng: NDArray[np.float32], pitch: float, radius: float, max_step: int,
                  cot: float, v0: int, v1: int, out: NDArray[np.float32]) -> None:
    """out[v, u] for rows v0 <= v < v1 = the unit normal at each pixel toward the camera (against its ray), NaN
    where it has no usable neighbour along a row or a column (grid_normals).  Each tangent is the three-point
    derivative (chord-length weighted) through the pixel and its farthest usable neighbour up to `step` pixels
    away on either side (step: radius / (pitch * range), 1 to max_step), or the difference with the one side that
    has one.  A neighbour is across a depth edge (unusable) when its range differs by more than a surface at
    VEIL_ANGLE_DEG to the ray spans over its distance in pixels, plus the depth noise (the veil test along the
    ray)."""
    w = rng.shape[1]
    r0 = r1 = r2 = 0.0
    for v in range(v0, v1):
        for u in range(w):
            r = np.float64(rng[v, u])
            if not np.isfinite(r):
                continue
            noise = NOISE_STEPS * DEPTH_NOISE * r * r
            span = pitch * r  # one pixel's width on a surface facing the camera (m)
            first = int(min(max(np.rint(radius / span), 1.0), float(max_step)))
            ok = True
            for axis in range(2):  # 0: along a column (rows), 1: along a row (columns)
                dv, du = (1, 0) if axis == 0 else (0, 1)
                # each side's farthest usable neighbour up to `first` pixels away: near a hole or an edge the
                # side that reaches it comes closer, and the three-point derivative allows unequal sides
                sf = first
                while sf > 0 and not _usable(rng, r, v + sf * dv, u + sf * du, sf * span * cot + noise):
                    sf -= 1
                sb = first
                while sb > 0 and not _usable(rng, r, v - sb * dv, u - sb * du, sb * span * cot + noise):
                    sb -= 1
                if sf == 0 and sb == 0:
                    ok = False
                    break
                qf, pf, qb, pb = v + sf * dv, u + sf * du, v - sb * dv, u - sb * du
                c0, c1, c2 = np.float64(ray[v, u, 0]), np.float64(ray[v, u, 1]), np.float64(ray[v, u, 2])
                f0, f1, f2 = np.float64(ray[qf, pf, 0]) - c0, np.float64(ray[qf, pf, 1]) - c1, \
                    np.float64(ray[qf, pf, 2]) - c2
                b0, b1, b2 = c0 - np.float64(ray[qb, pb, 0]), c1 - np.float64(ray[qb, pb, 1]), \
                    c2 - np.float64(ray[qb, pb, 2])
                lf = np.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
                lb = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
                if lf > 0.0 and lb > 0.0:
                    # the derivative of the parabola through the three points, parametrised by chord length:
                    # exact to first order on a curved surface however unequal the two sides' spans (a central
                    # difference tilts toward the longer side's curvature)
                    wf, wb = lb / lf, lf / lb
                else:
                    wf, wb = 1.0, 1.0
                t0, t1, t2 = wf * f0 + wb * b0, wf * f1 + wb * b1, wf * f2 + wb * b2
                if axis == 0:
                    r0, r1, r2 = t0, t1, t2
            if not ok:
                continue
            nx = t1 * r2 - t2 * r1  # (along a row) x (along a column)
            ny = t2 * r0 - t0 * r2
            nz = t0 * r1 - t1 * r0
            norm = np.sqrt(nx * nx + ny * ny + nz * nz)
            if norm == 0.0:
                continue
            if nx * np.float64(ray[v, u, 0]) + ny * np.float64(ray[v, u, 1]) + nz * np.float64(ray[v, u, 2]) > 0.0:
                norm = -norm  # toward the camera: against the ray
            out[v, u, 0] = nx / norm
            out[v, u, 1] = ny / norm
            out[v, u, 2] = nz / norm


@dataclass(frozen=True)
class RayImage:
    """An organised cloud as an image: ray (H, W, 3) float32, each pixel's point minus the camera that saw it
    (m), and rng (H, W) its length; NaN at pixels with no point (or one left out).  Kernels compute in float64."""

    grid: CloudGrid
    ray: NDArray[np.float32]
    rng: NDArray[np.float32]

    @classmethod
    def of(cls, points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
           grid: CloudGrid, keep: NDArray[np.bool_] | None = None) -> RayImage:
        """The image of the points keep says (all when None)."""
        ray = np.full((grid.height, grid.width, 3), np.nan, np.float32)
        rng = np.full((grid.height, grid.width), np.nan, np.float32)
        _fill(np.ascontiguousarray(points, np.float32), np.ascontiguousarray(camera_source, np.int32),
              np.ascontiguousarray(viewpoints, np.float32), grid.pixel,
              np.zeros(0, np.bool_) if keep is None else np.ascontiguousarray(keep, np.bool_), grid.width, ray, rng)
        return cls(grid, ray, rng)

    def at_points(self, image: NDArray[np.generic]) -> NDArray[np.generic]:
        """The per-pixel values (H, W, ...) of each point of the cloud, in its row order."""
        return image.reshape(self.grid.height * self.grid.width, *image.shape[2:])[self.grid.pixel]

    def veil(self) -> NDArray[np.bool_]:
        """(H, W) True at the mixed (flying) pixels: those farther than a neighbour they form a veil pair with,
        among their 8 image neighbours (_is_veil)."""
        drop = np.zeros(self.rng.shape, bool)
        h = self.rng.shape[0]

        def band(v0: int) -> None:
            _veil_pass(self.ray, self.rng, _COT, v0, min(h, v0 + ROWS_PER_TASK), drop)

        THREADS.map(band, range(0, h, ROWS_PER_TASK))
        return drop

    def pitch(self) -> float:
        """The image's angular pixel pitch (rad): the median of spacing / range between horizontal neighbours that
        are no veil pair, every PITCH_ROW_STRIDE-th row (about 1/fx for a pinhole camera): from the points
        alone, no intrinsics needed; NaN when no pair has both points."""
        ray, rng = self.ray[::PITCH_ROW_STRIDE], self.rng[::PITCH_ROW_STRIDE]
        out = np.empty(rng.size)
        count = _pitch_samples(ray, rng, _COT, out)
        return float(np.median(out[:count])) if count else float("nan")

    def normals(self, radius: float, skip: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
        """(H, W, 3) unit normals toward the camera (grid_normals), NaN where none; the pixels skip (H, W) says
        (the mixed ones) are left out: no normal, and no neighbour of another."""
        rng = self.rng if skip is None else np.where(skip, np.float32(np.nan), self.rng)
        pitch = RayImage(self.grid, self.ray, rng).pitch()
        if not np.isfinite(pitch) or pitch <= 0.0:
            pitch = 1.0 / 525.0  # no neighbouring pair to measure: a VGA depth camera's
        out = np.full(self.ray.shape, np.nan, np.float32)
        h = rng.shape[0]

        def band(v0: int) -> None:
            _normals_pass(self.ray, rng, pitch, float(radius), MAX_NORMAL_STEP, _COT, v0,
                          min(h, v0 + ROWS_PER_TASK), out)

        THREADS.map(band, range(0, h, ROWS_PER_TASK))
        return out


def veil_points(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                grid: CloudGrid, keep: NDArray[np.bool_] | None = None) -> NDArray[np.bool_]:
    """(N,) True at the mixed (flying) pixels of an organised cloud: the farther point of every veil pair among
    its 8 image neighbours (_is_veil), over the points keep says (all when None; the others are not tested and
    are no neighbours)."""
    image = RayImage.of(points, camera_source, viewpoints, grid, keep)
    return np.asarray(image.at_points(image.veil()), bool)


def grid_normals(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                 grid: CloudGrid, radius: float, keep: NDArray[np.bool_] | None = None) -> NDArray[np.float32]:
    """Unit normals (N,3) float32 of an organised cloud from its image neighbours, toward the camera that saw each
    point: the cross product of the row and column tangents (_normals_pass) between neighbours about `radius` (m)
    apart on the surface, that is radius / (pixel pitch * range) pixels (1 to MAX_NORMAL_STEP), falling back to
    the next pixels where those are missing; NaN where a pixel has no usable neighbour along a row or a column.
    Only the points keep says are used (all when None); the others' normals are NaN."""
    image = RayImage.of(points, camera_source, viewpoints, grid, keep)
    return np.asarray(image.at_points(image.normals(radius)), np.float32)


def clean_normals(points: NDArray[np.floating], camera_source: NDArray[np.int32], viewpoints: NDArray[np.floating],
                  grid: CloudGrid, radius: float | None, keep: NDArray[np.bool_] | None = None
                  ) -> tuple[NDArray[np.bool_], NDArray[np.float32] | None]:
    """veil_points and, with a radius, grid_normals of the points that are no veil, from one image: (the (N,)
    mixed-pixel mask, the (N, 3) normals or None)."""
    image = RayImage.of(points, camera_source, viewpoints, grid, keep)
    veil = image.veil()
    mixed = np.asarray(image.at_points(veil), bool)
    if radius is None:
        return mixed, None
    return mixed, np.asarray(image.at_points(image.normals(radius, skip=veil)), np.float32)
