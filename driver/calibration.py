"""The camera's calibration block (spec §5) and the lens model that turns pixels into rays."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from tofcut._types import F64
from tofcut.driver.errors import ProtocolError
from tofcut.driver.protocol import (
    CALIB_HEADER_SIZE,
    CALIB_MAGIC,
    MOD_FREQ_MHZ,
    check_sensor_size,
    crc32,
)

_CALIB = struct.Struct("<4sHHHHB3x9ff4x")
PHASE_OFFSET_UNIT = 1e-4
"""Phase offsets are stored as i16 in units of 1e-4 rad."""


@dataclass(frozen=True, eq=False)
class Calibration:
    """Intrinsics, Brown–Conrady distortion, distance offset and per-pixel phase offsets."""

    width: int
    height: int
    mod_code: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    distance_offset_m: float = 0.0
    phase_offset_raw: npt.NDArray[np.int16] = field(
        default_factory=lambda: np.zeros((0, 0), np.int16)
    )
    """Per-pixel phase offsets as stored, i16 in units of 1e-4 rad, shape (H, W)."""

    def __post_init__(self) -> None:
        if self.phase_offset_raw.size == 0:
            object.__setattr__(
                self, "phase_offset_raw", np.zeros((self.height, self.width), np.int16)
            )
        if self.phase_offset_raw.shape != (self.height, self.width):
            raise ValueError(
                f"phase offsets have shape {self.phase_offset_raw.shape}, "
                f"expected {(self.height, self.width)}"
            )
        self.phase_offset_raw.flags.writeable = False

    @property
    def phase_offset(self) -> F64:
        """Per-pixel phase offsets in radians, (H, W)."""
        return self.phase_offset_raw.astype(np.float64) * PHASE_OFFSET_UNIT

    @property
    def distortion(self) -> tuple[float, float, float, float, float]:
        """(k1, k2, p1, p2, k3), OpenCV's order."""
        return (self.k1, self.k2, self.p1, self.p2, self.k3)

    @property
    def size(self) -> int:
        """Bytes of this block when packed."""
        return CALIB_HEADER_SIZE + 2 * self.width * self.height


def pack_calibration(calib: Calibration) -> bytes:
    """The calibration block as it lies in the camera's flash."""
    head = _CALIB.pack(
        CALIB_MAGIC,
        1,
        CALIB_HEADER_SIZE,
        calib.width,
        calib.height,
        calib.mod_code,
        calib.fx,
        calib.fy,
        calib.cx,
        calib.cy,
        calib.k1,
        calib.k2,
        calib.p1,
        calib.p2,
        calib.k3,
        calib.distance_offset_m,
    )
    body = calib.phase_offset_raw.astype("<i2").tobytes()
    crc = crc32(head + body)
    return head + struct.pack("<I", crc) + body


def parse_calibration(
    data: bytes | bytearray | memoryview, width: int | None = None, height: int | None = None
) -> Calibration:
    """Parse and check a calibration block; `width`/`height` are what the device reported."""
    data = bytes(data)
    if len(data) < CALIB_HEADER_SIZE:
        raise ProtocolError(f"calibration block is {len(data)} bytes, shorter than its header")
    (magic, version, header_size, w, h, mod_code, *floats) = _CALIB.unpack(data[:60])
    if magic != CALIB_MAGIC:
        raise ProtocolError(f"calibration magic is {magic!r}, expected {CALIB_MAGIC!r}")
    if version != 1 or header_size != CALIB_HEADER_SIZE:
        raise ProtocolError(f"calibration version {version} / header {header_size} not supported")
    if why := check_sensor_size(w, h):
        raise ProtocolError(f"calibration block is for {why}")
    if width is not None and height is not None and (w, h) != (width, height):
        raise ProtocolError(f"calibration block is for {w}x{h}, the sensor is {width}x{height}")
    expected = CALIB_HEADER_SIZE + 2 * w * h
    if len(data) != expected:
        raise ProtocolError(f"calibration block is {len(data)} bytes, expected {expected}")
    (crc,) = struct.unpack("<I", data[60:64])
    if crc != crc32(data[:60] + data[64:]):
        raise ProtocolError("calibration block fails its CRC")
    if mod_code not in MOD_FREQ_MHZ:
        raise ProtocolError(f"calibration made at unsupported frequency code {mod_code}")
    fx, fy, cx, cy, k1, k2, p1, p2, k3, offset = floats
    if not (np.isfinite(floats).all() and fx > 0 and fy > 0):
        raise ProtocolError("calibration block holds non-finite or non-positive intrinsics")
    phase = np.frombuffer(data, "<i2", offset=CALIB_HEADER_SIZE).reshape(h, w).astype(np.int16)
    return Calibration(w, h, mod_code, fx, fy, cx, cy, k1, k2, p1, p2, k3, offset, phase)


def distort(calib: Calibration, xn: F64, yn: F64) -> tuple[F64, F64]:
    """Brown–Conrady: normalised undistorted coordinates → normalised distorted ones."""
    k1, k2, p1, p2, k3 = calib.distortion
    r2 = xn * xn + yn * yn
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
    yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
    return xd, yd


def undistort(
    calib: Calibration, xd: F64, yd: F64, tol: float = 1e-12, max_iter: int = 50
) -> tuple[F64, F64]:
    """Invert `distort` by Newton's method until every point moves by less than `tol`.

    Fixed-point iteration (OpenCV's way) stops tens of micrometres short in the corners;
    Newton converges quadratically, so a handful of steps reach machine precision.
    """
    k1, k2, p1, p2, k3 = calib.distortion
    x = xd.copy()
    y = yd.copy()
    for _ in range(max_iter):
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = 2.0 * k1 + r2 * (4.0 * k2 + 6.0 * k3 * r2)
        fx_ = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) - xd
        fy_ = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y - yd
        j11 = radial + dradial * x * x + 2.0 * p1 * y + 6.0 * p2 * x
        j12 = dradial * x * y + 2.0 * p1 * x + 2.0 * p2 * y
        j21 = dradial * x * y + 2.0 * p1 * x + 2.0 * p2 * y
        j22 = radial + dradial * y * y + 6.0 * p1 * y + 2.0 * p2 * x
        det = j11 * j22 - j12 * j21
        dx = (j22 * fx_ - j12 * fy_) / det
        dy = (j11 * fy_ - j21 * fx_) / det
        x -= dx
        y -= dy
        if (
            max(float(np.max(np.abs(dx), initial=0.0)), float(np.max(np.abs(dy), initial=0.0)))
            < tol
        ):
            return x, y
    raise ProtocolError("lens model does not invert: the distortion coefficients are implausible")


def pixel_rays(calib: Calibration) -> F64:
    """Unit ray direction of every pixel centre, (H, W, 3), camera frame x right, y down, z fwd."""
    v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
    xn, yn = undistort(calib, (u - calib.cx) / calib.fx, (v - calib.cy) / calib.fy)
    rays = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    return rays


def project(calib: Calibration, points: F64) -> F64:
    """Camera-frame points (..., 3) → pixel coordinates (..., 2) through the lens model."""
    z = points[..., 2]
    xd, yd = distort(calib, points[..., 0] / z, points[..., 1] / z)
    return np.stack([xd * calib.fx + calib.cx, yd * calib.fy + calib.cy], axis=-1)
