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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]


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
