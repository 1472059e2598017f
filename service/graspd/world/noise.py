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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]


@dataclass(frozen=True)
class DepthNoise:
    """Noise parameters; scale multiplies both noise sigmas (0 = exact depth, still quantized and
    dropped unless quantize/dropouts are off).  Angles in degrees, lengths in metres."""

    scale: float = 1.0
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

    def to_dict(self) -> dict[str, float | bool]:
        return asdict(self)


def axial_sigma(z: F32, theta: F32) -> F32:
    """Nguyen et al. 2012 axial standard deviation (m) at depth z (m) and incidence angle theta (rad)."""
    theta = np.minimum(theta, np.float32(np.deg2rad(89.0)))
    ang = 0.0001 / np.sqrt(np.maximum(z, 1e-3)) * theta**2 / (np.pi / 2 - theta) ** 2
    return (0.0012 + 0.0019 * (z - 0.4) ** 2 + ang).astype(np.float32)


def lateral_sigma_px(theta: F32) -> F32:
    """Nguyen et al. 2012 lateral standard deviation (pixels) at incidence angle theta (rad)."""
    theta = np.minimum(theta, np.float32(np.deg2rad(89.0)))
    return (0.8 + 0.035 * theta / (np.pi / 2 - theta)).astype(np.float32)


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
    out = zc + params.scale * axial_sigma(zc, theta) * rng.standard_normal(z.shape).astype(np.float32)
    lat = params.scale * lateral_sigma_px(theta)
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
