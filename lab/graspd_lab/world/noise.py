"""A structured-light depth-sensor noise model (Kinect v1 / Asus Xtion class), applied to depth images.

Axial noise follows Nguyen, Izadi and Lovell, "Modeling Kinect Sensor Noise for Improved 3D
Reconstruction and Tracking" (3DIMPVT 2012), eq. for theta < 60 deg extended with their angle term:
    sigma_z(z, theta) = 0.0012 + 0.0019 (z - 0.4)^2 + 0.0001 / sqrt(z) * theta^2 / (pi/2 - theta)^2   (m)
(close to Khoshelham and Elberink 2012's 1.425e-3 z^2 at 0.5-1.5 m); lateral noise
    sigma_L(theta) = 0.8 + 0.035 theta / (pi/2 - theta)   (pixels).
Disparity is quantized to 1/8 pixel (Kinect's sub-pixel step), d = f b / z with baseline b = 7.5 cm,
so depth steps grow as z^2 / (8 f b).  Pixels go missing at grazing incidence (a linear dropout ramp
between two angles), next to depth discontinuities (the projector/camera baseline shadows edges and
the stereo matcher fails there) and at random.

DepthNoise is the one parameter set for every renderer.  apply_depth_noise applies it to a raycast
depth image whose surface normals are known (graspd_lab.world.render); noisy_depth applies the subset a
rasterised depth image supports (graspd_lab.sim's pybullet cameras: normals estimated from the depth,
axial noise without the angle term, no lateral noise or quantization, a hard grazing cut).
DepthNoise.benchmark() is the clutter benchmark's model (its figures were measured with it).

Beside it, two other sensors' models for rasterised depth images, behind one interface (SensorNoise: a
`rasterised(depth, rays, rng, surfaces)` method and the materials it draws): StereoNoise, an active-stereo camera
of the RealSense D4xx class (disparity noise, so depth noise grows with range squared; speckle blobs; streaks of
foreground depth at depth edges along the baseline; holes on dark and shiny surfaces), and ToFNoise, a
time-of-flight camera (flying pixels between foreground and background at depth edges; a positive multipath bias
near concave corners).  sensor_noise(name) gives each sensor's default model; training scenes draw one per scene
(graspd_lab.training.scene_data), benchmarks keep DepthNoise.benchmark().
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from graspd.core.types import F32, F64


@dataclass(frozen=True)
class DepthNoise:
    """Noise parameters; scale multiplies both noise sigmas (0 = exact depth, still quantized and
    dropped unless quantize/dropouts are off).  Angles in degrees, lengths in metres.

    Axial sigma (m) = axial_base + axial_quadratic (z - 0.4)^2 + axial_angle / sqrt(z) theta^2 / (pi/2 - theta)^2,
    lateral sigma (px) = lateral_px + lateral_angle_px theta / (pi/2 - theta) (defaults: Nguyen et al. 2012).
    Pixels drop with a probability rising linearly from 0 at grazing_start_deg to 1 at grazing_end_deg
    (equal angles: a hard cut), with edge_dropout next to depth jumps over edge_jump, and at random_dropout."""

    scale: float = 1.0
    axial_base: float = 0.0012
    axial_quadratic: float = 0.0019
    axial_angle: float = 0.0001
    lateral_px: float = 0.8
    lateral_angle_px: float = 0.035
    quantize: bool = True
    baseline: float = 0.075
    subpixel: float = 1.0 / 8.0
    grazing_start_deg: float = 60.0
    grazing_end_deg: float = 80.0
    edge_jump: float = 0.01
    edge_dropout: float = 0.6
    random_dropout: float = 0.002

    @staticmethod
    def none() -> DepthNoise:
        """Exact depth: no noise, no quantization, no missing pixels (except where no surface is hit)."""
        return DepthNoise(scale=0.0, quantize=False, grazing_start_deg=90.0, grazing_end_deg=90.0,
                          edge_dropout=0.0, random_dropout=0.0)

    @staticmethod
    def benchmark() -> DepthNoise:
        """The clutter benchmark's model (graspd_lab.sim): axial sigma 0.0012 + 0.0019 (z - 0.4)^2 only, no
        quantization, pixels beyond 78 deg incidence dropped, half the pixels at depth edges, 1% at random."""
        return DepthNoise(axial_angle=0.0, lateral_px=0.0, lateral_angle_px=0.0, quantize=False,
                          grazing_start_deg=78.0, grazing_end_deg=78.0, edge_jump=0.01, edge_dropout=0.5,
                          random_dropout=0.01)

    def to_dict(self) -> dict[str, float | bool]:
        return asdict(self)

    @property
    def sensor(self) -> str:
        return "kinect"

    def draw_surfaces(self, ids: NDArray[np.int64], rng: np.random.Generator) -> Surfaces | None:
        """No materials: the structured-light model treats every surface alike (draws nothing)."""
        return None

    def rasterised(self, depth: F64, rays: F64, rng: np.random.Generator, surfaces: Surfaces | None = None) -> F64:
        """noisy_depth with these parameters (surfaces unused)."""
        return noisy_depth(depth, rays, self, rng)


def axial_sigma(z: F32, theta: F32, base: float = 0.0012, quadratic: float = 0.0019, angle: float = 0.0001) -> F32:
    """Axial standard deviation (m) at depth z (m) and incidence angle theta (rad); defaults Nguyen et al. 2012."""
    theta = np.minimum(theta, np.float32(np.deg2rad(89.0)))
    ang = angle / np.sqrt(np.maximum(z, 1e-3)) * theta**2 / (np.pi / 2 - theta) ** 2
    return (base + quadratic * (z - 0.4) ** 2 + ang).astype(np.float32)


def lateral_sigma_px(theta: F32, base: float = 0.8, angle: float = 0.035) -> F32:
    """Lateral standard deviation (pixels) at incidence angle theta (rad); defaults Nguyen et al. 2012."""
    theta = np.minimum(theta, np.float32(np.deg2rad(89.0)))
    return (base + angle * theta / (np.pi / 2 - theta)).astype(np.float32)


def quantize_depth(z: F32, focal_px: float, baseline: float, subpixel: float) -> F32:
    """Depth after rounding the disparity f b / z to multiples of subpixel pixels."""
    fb = focal_px * baseline
    disparity = fb / np.maximum(z, 1e-6)
    q = np.maximum(np.rint(disparity / subpixel), 1.0) * subpixel
    return (fb / q).astype(np.float32)


def depth_edges(z: F32, jump: float) -> NDArray[np.bool_]:
    """Pixels (H,W) with a 4-neighbour whose depth differs by more than jump (m) or that is missing."""
    filled = np.where(np.isfinite(z), z, np.inf)
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        with np.errstate(invalid="ignore"):
            d = np.abs(np.diff(filled, axis=axis))
        big = ~(d <= jump)  # inf - finite and nan count as edges
        lo = [slice(None)] * 2
        hi = [slice(None)] * 2
        lo[axis] = slice(0, -1)
        hi[axis] = slice(1, None)
        edge[tuple(lo)] |= big
        edge[tuple(hi)] |= big
    return edge & np.isfinite(z)


def apply_depth_noise(z: F32, cos_incidence: F32, focal_px: float, params: DepthNoise,
                      rng: np.random.Generator) -> tuple[F32, F32, F32]:
    """Noisy depth (H,W) with NaN where missing, and lateral pixel offsets (du, dv) (H,W) to apply
    when back-projecting.  z: exact depth (m, NaN = no surface); cos_incidence: |cos| of the angle
    between the viewing ray and the surface normal."""
    valid = np.isfinite(z)
    theta = np.arccos(np.clip(cos_incidence, 0.0, 1.0)).astype(np.float32)
    zc = np.where(valid, z, 1.0).astype(np.float32)
    axial = axial_sigma(zc, theta, params.axial_base, params.axial_quadratic, params.axial_angle)
    out = zc + params.scale * axial * rng.standard_normal(z.shape).astype(np.float32)
    lat = params.scale * lateral_sigma_px(theta, params.lateral_px, params.lateral_angle_px)
    du = (lat * rng.standard_normal(z.shape)).astype(np.float32)
    dv = (lat * rng.standard_normal(z.shape)).astype(np.float32)
    if params.quantize:
        out = quantize_depth(out, focal_px, params.baseline, params.subpixel)
    keep = valid.copy()
    start, end = np.deg2rad(params.grazing_start_deg), np.deg2rad(params.grazing_end_deg)
    if end > start:
        p_drop = np.clip((theta - start) / (end - start), 0.0, 1.0)
        keep &= rng.random(z.shape) >= p_drop
    else:
        keep &= theta < end
    if params.edge_dropout > 0.0:
        keep &= ~(depth_edges(z, params.edge_jump) & (rng.random(z.shape) < params.edge_dropout))
    if params.random_dropout > 0.0:
        keep &= rng.random(z.shape) >= params.random_dropout
    return np.where(keep, out, np.nan).astype(np.float32), du, dv


def noisy_depth(depth: F64, rays: F64, noise: DepthNoise, rng: np.random.Generator) -> F64:
    """A rasterised depth image (H, W; m along the optical axis, inf = nothing hit) with noise applied;
    dropped pixels become inf.  rays (H, W, 3): world-frame rays at unit depth.  Normals come from
    neighbouring points (central differences); supports axial noise without the angle term, a hard
    grazing cut, edge and random dropout (ValueError for the rest: quantization, lateral noise, a ramp)."""
    _check_rasterised(noise)
    z = depth.copy()
    finite = np.isfinite(z)
    pts = rays * np.where(finite, z, 0.0)[..., None]
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dv[1:-1] = pts[2:] - pts[:-2]
    nrm = np.cross(du, dv)
    nlen = np.linalg.norm(nrm, axis=-1)
    cosang = np.abs(np.einsum("hwk,hwk->hw", nrm, rays)) / np.maximum(nlen * np.linalg.norm(rays, axis=-1), 1e-12)
    grazing = (nlen > 0) & (cosang < np.cos(np.deg2rad(noise.grazing_end_deg)))
    zf = np.where(finite, z, 1e3)
    jump = np.zeros(z.shape, bool)
    jump[:, 1:] |= np.abs(np.diff(zf, axis=1)) > noise.edge_jump
    jump[:, :-1] |= np.abs(np.diff(zf, axis=1)) > noise.edge_jump
    jump[1:] |= np.abs(np.diff(zf, axis=0)) > noise.edge_jump
    jump[:-1] |= np.abs(np.diff(zf, axis=0)) > noise.edge_jump
    drop = grazing | (jump & (rng.random(z.shape) < noise.edge_dropout)) | (rng.random(z.shape) < noise.random_dropout)
    sigma = noise.scale * (noise.axial_base + noise.axial_quadratic * (np.where(finite, z, 0.4) - 0.4) ** 2)
    z = z + rng.normal(size=z.shape) * sigma
    z[drop] = np.inf
    return z


def _check_rasterised(noise: DepthNoise) -> None:
    """ValueError for the parts of a DepthNoise that noisy_depth does not model."""
    unsupported = []
    if noise.quantize:
        unsupported.append("quantize")
    if noise.scale != 0.0 and (noise.axial_angle or noise.lateral_px or noise.lateral_angle_px):
        unsupported.append("axial_angle/lateral noise")
    if noise.grazing_start_deg < noise.grazing_end_deg:
        unsupported.append("a grazing ramp (grazing_start_deg < grazing_end_deg)")
    if unsupported:
        raise ValueError(f"noisy_depth (rasterised depth) does not model {', '.join(unsupported)}: "
                         "use DepthNoise.benchmark() or DepthNoise.none()")


# ---- other sensors: one interface, chosen per training scene ----


@dataclass(frozen=True)
class Surfaces:
    """Which surface every pixel of a depth image shows (ids (H, W), -1 = none; the simulator's body ids) and the
    surfaces of dark (absorbing the projector's pattern) and shiny (specular) material."""

    ids: NDArray[np.int64]
    dark: frozenset[int] = frozenset()
    shiny: frozenset[int] = frozenset()


class SensorNoise(Protocol):
    """A depth sensor's noise model for rasterised depth images (H, W; m along the optical axis, inf = nothing
    hit) with world-frame unit-depth rays (H, W, 3)."""

    @property
    def sensor(self) -> str:
        """The sensor's name: "kinect", "stereo" or "tof"."""
        ...

    def draw_surfaces(self, ids: NDArray[np.int64], rng: np.random.Generator) -> Surfaces | None:
        """The materials of the surfaces of one observation (ids: (H, W) ids of one image, or the ids in view),
        drawn once so that every camera of the observation sees the same; None when the model needs none."""
        ...

    def rasterised(self, depth: F64, rays: F64, rng: np.random.Generator, surfaces: Surfaces | None = None) -> F64:
        """The depth image with the sensor's noise; missing pixels are inf."""
        ...


def cos_incidence(depth: F64, rays: F64) -> F64:
    """|cos| of the angle between each pixel's ray and its surface normal (H, W), the normal from neighbouring
    points (central differences); 1 where no normal can be formed."""
    finite = np.isfinite(depth)
    pts = rays * np.where(finite, depth, 0.0)[..., None]
    du = np.zeros_like(pts)
    dv = np.zeros_like(pts)
    du[:, 1:-1] = pts[:, 2:] - pts[:, :-2]
    dv[1:-1] = pts[2:] - pts[:-2]
    nrm = np.cross(du, dv)
    nlen = np.linalg.norm(nrm, axis=-1)
    cosang = np.abs(np.einsum("hwk,hwk->hw", nrm, rays)) / np.maximum(nlen * np.linalg.norm(rays, axis=-1), 1e-12)
    return np.where(nlen > 0, cosang, 1.0)


def jump_mask(depth: F64, jump: float) -> NDArray[np.bool_]:
    """Pixels (H, W) with a 4-neighbour whose depth differs by more than jump (m), inf counting as far away."""
    zf = np.where(np.isfinite(depth), depth, 1e3)
    out = np.zeros(depth.shape, bool)
    dx = np.abs(np.diff(zf, axis=1)) > jump
    dy = np.abs(np.diff(zf, axis=0)) > jump
    out[:, 1:] |= dx
    out[:, :-1] |= dx
    out[1:] |= dy
    out[:-1] |= dy
    return out


def _draw_materials(ids: NDArray[np.int64], rng: np.random.Generator, dark_share: float, shiny_share: float
                    ) -> Surfaces:
    """Each surface id (>= 0) in ids is dark with probability dark_share, else shiny with shiny_share."""
    present = np.unique(ids[ids >= 0])
    u = rng.random(len(present))
    dark = frozenset(int(i) for i in present[u < dark_share])
    shiny = frozenset(int(i) for i in present[(u >= dark_share) & (u < dark_share + shiny_share)])
    return Surfaces(ids=ids, dark=dark, shiny=shiny)


def _surface_mask(surfaces: Surfaces, which: frozenset[int]) -> NDArray[np.bool_]:
    return np.isin(surfaces.ids, np.fromiter(which, np.int64, len(which))) if which else np.zeros(
        surfaces.ids.shape, bool)


@dataclass(frozen=True)
class StereoNoise:
    """An active-stereo camera of the RealSense D4xx class (lengths m, angles deg, disparities px of the sensor's
    own image: focal_px at its native resolution, baseline b).

    Depth noise is disparity noise: sigma_z = z^2 subpixel / (focal_px b), growing with range squared.  Speckle:
    blobs (speckle_radius_px) seeded at speckle_share of the pixels, whose disparity is off by N(0,
    speckle_disparity_px).  Edge streaks: at a depth jump (> edge_jump) along the baseline (image rows) the
    foreground's depth runs up to streak_px pixels into the background (the matcher's window straddles the edge),
    and edge_dropout of the edge pixels are missing.  Holes: a surface is dark with probability dark_share (missing
    with dark_dropout per pixel) or shiny with shiny_share (missing where it faces the camera within specular_deg,
    the projector's highlight); beyond grazing_deg every pixel is missing, and random_dropout at random."""

    focal_px: float = 425.0
    baseline: float = 0.050
    subpixel: float = 0.08
    speckle_share: float = 0.002
    speckle_radius_px: int = 2
    speckle_disparity_px: float = 0.6
    edge_jump: float = 0.01
    streak_px: int = 6
    edge_dropout: float = 0.3
    dark_share: float = 0.15
    dark_dropout: float = 0.85
    shiny_share: float = 0.15
    specular_deg: float = 20.0
    grazing_deg: float = 80.0
    random_dropout: float = 0.003

    @property
    def sensor(self) -> str:
        return "stereo"

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def sigma(self, z: F64) -> F64:
        """Axial standard deviation (m) at depth z (m): z^2 subpixel / (focal_px baseline)."""
        return np.asarray(z) ** 2 * self.subpixel / (self.focal_px * self.baseline)

    def draw_surfaces(self, ids: NDArray[np.int64], rng: np.random.Generator) -> Surfaces | None:
        return _draw_materials(ids, rng, self.dark_share, self.shiny_share)

    def rasterised(self, depth: F64, rays: F64, rng: np.random.Generator, surfaces: Surfaces | None = None) -> F64:
        finite = np.isfinite(depth)
        z = np.where(finite, depth, np.inf)
        cosang = cos_incidence(depth, rays)
        fb = self.focal_px * self.baseline
        # disparity noise, then speckle blobs with a disparity offset of their own
        zc = np.where(finite, z, 1.0)
        noisy = zc + rng.standard_normal(z.shape) * self.sigma(zc)
        seeds = rng.random(z.shape) < self.speckle_share
        if seeds.any() and self.speckle_radius_px > 0:
            labels, n = ndimage.label(ndimage.binary_dilation(seeds, iterations=self.speckle_radius_px))
            offsets = np.r_[0.0, rng.normal(0.0, self.speckle_disparity_px, n)]
            blob_disp = offsets[labels]
            noisy = np.where(labels > 0, fb / np.maximum(fb / noisy + blob_disp, 1e-3), noisy)
        noisy = self._streaks(np.where(finite, noisy, np.inf), rng)
        drop = cosang < np.cos(np.deg2rad(self.grazing_deg))
        drop |= jump_mask(depth, self.edge_jump) & (rng.random(z.shape) < self.edge_dropout)
        drop |= rng.random(z.shape) < self.random_dropout
        if surfaces is not None:
            drop |= _surface_mask(surfaces, surfaces.dark) & (rng.random(z.shape) < self.dark_dropout)
            drop |= _surface_mask(surfaces, surfaces.shiny) & (cosang > np.cos(np.deg2rad(self.specular_deg)))
        out = np.where(drop, np.inf, noisy)
        return np.where(np.isfinite(out) & (out > 0), out, np.inf)

    def _streaks(self, z: F64, rng: np.random.Generator) -> F64:
        """Foreground depth run into the background along rows, up to streak_px pixels past each depth jump."""
        if self.streak_px <= 0:
            return z
        out = z.copy()
        zf = np.where(np.isfinite(z), z, 1e3)
        for direction in (1, -1):
            # fg: pixels whose neighbour in this direction is further by more than edge_jump
            nxt = np.roll(zf, -direction, axis=1)
            fg = nxt - zf > self.edge_jump
            if direction == 1:
                fg[:, -1] = False
            else:
                fg[:, 0] = False
            length = np.where(fg, rng.integers(0, self.streak_px + 1, z.shape), 0)
            for k in range(1, self.streak_px + 1):
                src = fg & (length >= k)
                if not src.any():
                    break
                rows, cols = np.nonzero(src)
                tgt = cols + direction * k
                ok = (tgt >= 0) & (tgt < z.shape[1])
                rows, cols, tgt = rows[ok], cols[ok], tgt[ok]
                behind = zf[rows, tgt] - zf[rows, cols] > self.edge_jump
                out[rows[behind], tgt[behind]] = z[rows[behind], cols[behind]]
        return out


@dataclass(frozen=True)
class ToFNoise:
    """A time-of-flight camera (lengths m, angles deg, pixels of the rendered image).

    Axial noise sigma = axial_base + axial_linear z.  Flying pixels: within flying_px of a depth jump (> edge_jump)
    a pixel is, with probability flying_share, a mix of the nearest and furthest surface around it (a uniform
    blend of their depths), so points hang in the air between foreground and background.  Multipath: light
    bounced between two surfaces that meet in a concave corner arrives late, a positive depth bias: multipath_gain
    x how far the pixel lies behind the plane of its neighbours (inverse depth is linear on a plane, so the
    bias is 0 there), over multipath_radius_px and spread as far again, at most multipath_max.  Beyond
    grazing_deg pixels are missing, and random_dropout at random."""

    axial_base: float = 0.0015
    axial_linear: float = 0.0015
    edge_jump: float = 0.01
    flying_px: int = 2
    flying_share: float = 0.7
    multipath_radius_px: int = 6
    multipath_gain: float = 2.0
    multipath_max: float = 0.012
    grazing_deg: float = 82.0
    random_dropout: float = 0.002

    @property
    def sensor(self) -> str:
        return "tof"

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def draw_surfaces(self, ids: NDArray[np.int64], rng: np.random.Generator) -> Surfaces | None:
        return None

    def multipath_bias(self, depth: F64) -> F64:
        """The multipath depth bias (H, W; m, >= 0) of an exact depth image: large in concave corners, 0 on planes
        and next to depth jumps (those pixels fly instead)."""
        finite = np.isfinite(depth)
        r = self.multipath_radius_px
        if r <= 0:
            return np.zeros(depth.shape)
        inv = np.where(finite, 1.0 / np.where(finite, depth, 1.0), 0.0)
        size = 2 * r + 1
        weight = ndimage.uniform_filter(finite.astype(np.float64), size, mode="constant")
        mean_inv = ndimage.uniform_filter(inv, size, mode="constant") / np.maximum(weight, 1e-9)
        behind = np.where(finite, depth - 1.0 / np.maximum(mean_inv, 1e-9), 0.0)  # > 0: further than the neighbours
        near_jump = ndimage.binary_dilation(jump_mask(depth, self.edge_jump) | ~finite, iterations=r)
        raw = np.where(near_jump, 0.0, np.clip(behind, 0.0, None) * self.multipath_gain)
        spread = ndimage.maximum_filter(raw, size)
        return np.where(finite, np.minimum(spread, self.multipath_max), 0.0)

    def rasterised(self, depth: F64, rays: F64, rng: np.random.Generator, surfaces: Surfaces | None = None) -> F64:
        finite = np.isfinite(depth)
        zc = np.where(finite, depth, 1.0)
        out = zc + self.multipath_bias(depth)
        out = out + rng.standard_normal(depth.shape) * (self.axial_base + self.axial_linear * zc)
        # flying pixels: a blend of the nearest and furthest finite depth within flying_px
        size = 2 * self.flying_px + 1
        zmin = ndimage.minimum_filter(np.where(finite, depth, np.inf), size)
        zmax = ndimage.maximum_filter(np.where(finite, depth, -np.inf), size)
        edge = ndimage.binary_dilation(jump_mask(depth, self.edge_jump) & finite, iterations=self.flying_px)
        fly = edge & finite & np.isfinite(zmin) & (zmax - zmin > self.edge_jump)
        fly &= rng.random(depth.shape) < self.flying_share
        a = rng.random(depth.shape)
        out = np.where(fly, a * zmin + (1.0 - a) * np.where(np.isfinite(zmax), zmax, zmin), out)
        drop = cos_incidence(depth, rays) < np.cos(np.deg2rad(self.grazing_deg))
        drop |= rng.random(depth.shape) < self.random_dropout
        return np.where(finite & ~drop, out, np.inf)


#: Each sensor's default model: the clutter benchmark's Kinect, the D4xx-class stereo camera, the ToF camera.
SENSOR_MODELS: dict[str, Callable[[], SensorNoise]] = {
    "kinect": DepthNoise.benchmark, "stereo": StereoNoise, "tof": ToFNoise}


def sensor_noise(name: str) -> SensorNoise:
    """The default noise model of a sensor name (ValueError for an unknown one)."""
    if name not in SENSOR_MODELS:
        raise ValueError(f"sensor must be one of {sorted(SENSOR_MODELS)}, got {name!r}")
    return SENSOR_MODELS[name]()


def draw_sensor(mix: Sequence[tuple[str, float]], rng: np.random.Generator) -> str:
    """A sensor name drawn from a mix of (name, weight)."""
    names = [n for n, _ in mix]
    for n in names:
        if n not in SENSOR_MODELS:
            raise ValueError(f"sensor must be one of {sorted(SENSOR_MODELS)}, got {n!r}")
    weights = np.array([w for _, w in mix], np.float64)
    return names[int(rng.choice(len(names), p=weights / weights.sum()))]
