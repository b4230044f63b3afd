"""The emulated camera's true optics: calibration block, pixel rays and projection windows.

The rays are found by our own fixed-point inversion of Brown–Conrady, not the driver's
Newton solver, so tests that the driver undoes the distortion are not circular.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tofcut._types import F64
from tofcut.driver.calibration import PHASE_OFFSET_UNIT, Calibration


@dataclass(frozen=True)
class LensSpec:
    """Intrinsics and distortion of a scene's camera, as a scene file gives them."""

    width: int = 176
    height: int = 144
    fx: float = 250.0
    fy: float = 250.0
    cx: float = 87.6
    cy: float = 71.3
    k1: float = -0.2
    k2: float = 0.06
    p1: float = 0.0007
    p2: float = -0.0005
    k3: float = 0.0
    distance_offset_m: float = 0.012
    phase_offset_sigma_rad: float = 0.03
    """Random fixed-pattern phase offset per pixel (one standard deviation)."""
    phase_offset_ramp_rad: float = 0.02
    """A smooth part of the fixed pattern: this much more at the corners than the centre."""


def make_calibration(lens: LensSpec, mod_code: int, seed: int) -> Calibration:
    """The calibration block of an emulated camera; the phase pattern is random but seeded."""
    rng = np.random.default_rng([seed, 0x0CA1])
    v, u = np.mgrid[0 : lens.height, 0 : lens.width].astype(np.float64)
    rr = ((u - lens.cx) / lens.width) ** 2 + ((v - lens.cy) / lens.height) ** 2
    ramp = lens.phase_offset_ramp_rad * rr / max(float(rr.max()), 1e-12)
    pattern = ramp + rng.normal(0.0, lens.phase_offset_sigma_rad, rr.shape)
    raw = np.clip(np.rint(pattern / PHASE_OFFSET_UNIT), -32768, 32767).astype(np.int16)
    return Calibration(
        lens.width, lens.height, mod_code, lens.fx, lens.fy, lens.cx, lens.cy,
        lens.k1, lens.k2, lens.p1, lens.p2, lens.k3, lens.distance_offset_m, raw,
    )  # fmt: skip


def distort_normalised(calib: Calibration, x: F64, y: F64) -> tuple[F64, F64]:
    """Brown–Conrady forward model (OpenCV's meaning): undistorted → distorted coordinates."""
    r2 = x * x + y * y
    radial = 1.0 + r2 * (calib.k1 + r2 * (calib.k2 + r2 * calib.k3))
    xd = x * radial + 2.0 * calib.p1 * x * y + calib.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + calib.p1 * (r2 + 2.0 * y * y) + 2.0 * calib.p2 * x * y
    return xd, yd


def undistort_fixed_point(
    calib: Calibration, xd: F64, yd: F64, tol: float = 1e-14, max_iter: int = 500
) -> tuple[F64, F64]:
    """Invert the lens by fixed-point iteration run to convergence (not the driver's Newton)."""
    x = xd.copy()
    y = yd.copy()
    for _ in range(max_iter):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (calib.k1 + r2 * (calib.k2 + r2 * calib.k3))
        tx = 2.0 * calib.p1 * x * y + calib.p2 * (r2 + 2.0 * x * x)
        ty = calib.p1 * (r2 + 2.0 * y * y) + 2.0 * calib.p2 * x * y
        nx = (xd - tx) / radial
        ny = (yd - ty) / radial
        step = max(float(np.max(np.abs(nx - x))), float(np.max(np.abs(ny - y))))
        x, y = nx, ny
        if step < tol:
            return x, y
    raise ValueError("the lens model does not invert by fixed-point iteration")


def rays_at(calib: Calibration, u: F64, v: F64) -> F64:
    """Unit rays (3, …) through image positions (u, v) in pixels (pixel centres at integers)."""
    x, y = undistort_fixed_point(calib, (u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy)
    rays = np.stack([x, y, np.ones_like(x)])
    rays /= np.linalg.norm(rays, axis=0, keepdims=True)
    return rays


def subpixel_offsets(n: int) -> F64:
    """An n×n grid of sample offsets inside a pixel, (n², 2) as (du, dv), centred on 0."""
    steps = (np.arange(n) + 0.5) / n - 0.5
    du, dv = np.meshgrid(steps, steps)
    return np.stack([du.ravel(), dv.ravel()], axis=1)


@dataclass(frozen=True, eq=False)
class RayGrid:
    """Every ray the renderer casts: pixel centres (3, H, W) and sub-pixel samples (3, H, W, S)."""

    centre: F64
    sub: F64
    vignette: F64
    """Illumination and lens fall-off per pixel, cos(field angle)^n, (H, W)."""
    limit: float
    """Largest |x| or |y| of any undistorted normalised coordinate in view, with margin."""

    @classmethod
    def build(cls, calib: Calibration, supersample: int, falloff_exponent: float) -> RayGrid:
        """Cast the lens once: rays depend only on the calibration."""
        v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
        centre = rays_at(calib, u, v)
        off = subpixel_offsets(supersample)
        sub = rays_at(calib, u[..., None] + off[:, 0], v[..., None] + off[:, 1])
        vignette = centre[2] ** falloff_exponent
        half_x = np.abs(sub[0] / sub[2]).max()
        half_y = np.abs(sub[1] / sub[2]).max()
        return cls(centre, sub, vignette, float(max(half_x, half_y)) * 1.2 + 0.05)


def sphere_window(
    calib: Calibration, limit: float, centre: F64, radius: float
) -> tuple[int, int, int, int] | None:
    """Pixel rows/columns (v0, v1, u0, u1) that can see a sphere; None if none can.

    Exact tangent bounds in undistorted normalised coordinates, then the lens on the
    rectangle's boundary (the distortion is monotonic within the field of view), plus a
    pixel of margin.
    """
    x, y, z = (float(c) for c in centre)
    full = (0, calib.height, 0, calib.width)
    if z <= -radius:
        return None
    if z * z - radius * radius <= 1e-6 * z * z or z <= radius:
        return full
    bounds = []
    for a in (x, y):
        den = z * z - radius * radius
        root = radius * math.sqrt(max(a * a + z * z - radius * radius, 0.0))
        bounds.append(((a * z - root) / den, (a * z + root) / den))
    (x0, x1), (y0, y1) = bounds
    if x1 < -limit or x0 > limit or y1 < -limit or y0 > limit:
        return None
    x0, x1 = max(x0, -limit), min(x1, limit)
    y0, y1 = max(y0, -limit), min(y1, limit)
    s = np.linspace(0.0, 1.0, 9)
    xs = np.concatenate([x0 + (x1 - x0) * s, np.full(9, x1), x0 + (x1 - x0) * s, np.full(9, x0)])
    ys = np.concatenate([np.full(9, y0), y0 + (y1 - y0) * s, np.full(9, y1), y0 + (y1 - y0) * s])
    if x0 < 0.0 < x1:
        xs = np.append(xs, [0.0, 0.0])
        ys = np.append(ys, [y0, y1])
    if y0 < 0.0 < y1:
        xs = np.append(xs, [x0, x1])
        ys = np.append(ys, [0.0, 0.0])
    xd, yd = distort_normalised(calib, xs, ys)
    u = xd * calib.fx + calib.cx
    v = yd * calib.fy + calib.cy
    u0 = max(0, math.floor(float(u.min())) - 1)
    u1 = min(calib.width, math.ceil(float(u.max())) + 2)
    v0 = max(0, math.floor(float(v.min())) - 1)
    v1 = min(calib.height, math.ceil(float(v.max())) + 2)
    if u0 >= u1 or v0 >= v1:
        return None
    return v0, v1, u0, u1
