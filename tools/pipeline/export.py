"""Frames in the formats other tools open: PLY and PCD point clouds, 16-bit depth PNGs and
the intrinsics beside them (Open3D's `PinholeCameraIntrinsic`, ROS's `camera_info`).

Point clouds are written by `plyfile` and `pypcd4`, PNGs by Pillow: each format's own
well-kept library, so that what a reader expects (header fields, byte order, PCD's
`DATA binary` layout, PNG's 16-bit greyscale) is that library's concern, not ours.

Depth PNGs and the intrinsics
-----------------------------
A PNG pixel is z (along the optical axis, not the range along the ray) in millimetres,
rounded, as uint16; 0 where the pixel is invalid or z is outside 1..65535 mm. Pixels are
the sensor's own (not undistorted), so the PNG lines up with the amplitude image.

The camera's lens is Brown–Conrady (`driver.calibration.distort`: k1, k2, p1, p2, k3 in
OpenCV's order), which is ROS's `plumb_bob`: `camera_info` takes the calibration as it is
(K and D exact). Open3D's pinhole has no distortion, so its fx, fy, cx, cy are a pinhole
fitted to the rays: least squares of u = fx·x/z + cx (and v = fy·y/z + cy) over every
pixel centre, x/z and y/z from `pixel_rays`. What that pinhole gets wrong is written
beside it (`pinhole_fit`): the pixel residual (rms and max), and the largest lateral error
of a back-projected point, in millimetres per metre of depth. A lens without distortion
fits exactly (residual 0).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from PIL import Image

from tofcut.driver.calibration import Calibration, pixel_rays
from tofcut.driver.frames import Frame
from tofcut.driver.intrinsics import Intrinsics

DEPTH_SCALE = 1000.0
"""PNG units per metre (Open3D's `depth_scale`)."""
MAX_DEPTH_UNITS = 65535
INTRINSICS_NAME = "intrinsics.json"


def valid_points(frame: Frame) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """The valid pixels' points (N, 3) and amplitudes (N,), float32, in row-major order."""
    keep = frame.valid & np.isfinite(frame.xyz).all(axis=-1)
    return frame.xyz[keep].astype(np.float32), frame.amplitude[keep].astype(np.float32)


def _comments(frame: Frame) -> list[str]:
    return [
        "tofcut frame: camera frame x right, y down, z forward; metres",
        f"sequence {frame.sequence} device_time_us {frame.device_time_us} "
        f"host_time_ns {frame.host_time_ns}",
    ]


def write_ply(path: Path, frame: Frame) -> int:
    """A binary little-endian PLY: vertex x, y, z, amplitude (float32). Returns the points."""
    from plyfile import PlyData, PlyElement

    xyz, amplitude = valid_points(frame)
    vertex = np.empty(len(xyz), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("amplitude", "<f4")])
    vertex["x"], vertex["y"], vertex["z"] = xyz.T
    vertex["amplitude"] = amplitude
    element = PlyElement.describe(vertex, "vertex")
    PlyData([element], text=False, byte_order="<", comments=_comments(frame)).write(str(path))
    return len(xyz)


def write_pcd(path: Path, frame: Frame) -> int:
    """A PCD (`DATA binary`): fields x, y, z, amplitude (float32). Returns the points."""
    from pypcd4.pypcd4 import Encoding, PointCloud

    xyz, amplitude = valid_points(frame)
    cloud = PointCloud.from_points(
        [xyz[:, 0], xyz[:, 1], xyz[:, 2], amplitude],
        ("x", "y", "z", "amplitude"),
        (np.float32, np.float32, np.float32, np.float32),
    )
    cloud.save(path, encoding=Encoding.BINARY)
    return len(xyz)


def depth_mm(frame: Frame) -> npt.NDArray[np.uint16]:
    """z in millimetres, rounded; 0 where invalid or outside what uint16 holds."""
    z = frame.xyz[..., 2] * DEPTH_SCALE
    units = np.rint(np.where(np.isfinite(z), z, 0.0))
    keep = frame.valid & (units >= 1) & (units <= MAX_DEPTH_UNITS)
    return np.where(keep, units, 0).astype(np.uint16)


def write_depth_png(path: Path, frame: Frame) -> int:
    """A 16-bit greyscale PNG of `depth_mm`. Returns the non-zero pixels."""
    depth = depth_mm(frame)
    Image.fromarray(depth).save(path, format="PNG")
    return int(np.count_nonzero(depth))


def pinhole_fit(calib: Calibration) -> dict[str, float]:
    """The pinhole nearest the lens (`Intrinsics.fitted`) and its residual."""
    pinhole = Intrinsics.fitted(calib)
    rays = pixel_rays(calib)
    xn, yn = rays[..., 0] / rays[..., 2], rays[..., 1] / rays[..., 2]
    v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
    fx, fy, cx, cy = pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy
    pixels = np.hypot(u - (fx * xn + cx), v - (fy * yn + cy))
    lateral = np.hypot((u - cx) / fx - xn, (v - cy) / fy - yn)  # metres per metre of z
    return {
        "fx": fx,
        "fy": fy,
        "cx": cx,
        "cy": cy,
        "rms_px": float(np.sqrt(np.mean(pixels**2))),
        "max_px": float(pixels.max()),
        "max_lateral_mm_per_m": float(lateral.max() * 1000.0),
    }


def intrinsics(calib: Calibration) -> dict[str, Any]:
    """What `intrinsics.json` holds (see the module's docstring); `Intrinsics.from_json`
    reads it back."""
    fit = pinhole_fit(calib)
    pinhole = Intrinsics(
        width=calib.width, height=calib.height, fx=fit["fx"], fy=fit["fy"], cx=fit["cx"],
        cy=fit["cy"],
    )  # fmt: skip
    k = [calib.fx, 0.0, calib.cx, 0.0, calib.fy, calib.cy, 0.0, 0.0, 1.0]
    exact = not any(calib.distortion)
    return {
        **pinhole.to_json(),
        "depth_scale": DEPTH_SCALE,
        "depth": "z along the optical axis in millimetres (uint16), 0 where invalid",
        "pinhole_fit": {
            "method": "exact: the lens has no distortion"
            if exact
            else "least squares of u = fx*x/z + cx, v = fy*y/z + cy over every pixel centre's "
            "ray (the lens is plumb_bob: see camera_info for the exact model)",
            "rms_px": fit["rms_px"],
            "max_px": fit["max_px"],
            "max_lateral_mm_per_m": fit["max_lateral_mm_per_m"],
        },
        "camera_info": {
            "width": calib.width,
            "height": calib.height,
            "distortion_model": "plumb_bob",
            "D": [float(c) for c in calib.distortion],
            "K": [float(c) for c in k],
            "R": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            "P": [calib.fx, 0.0, calib.cx, 0.0, 0.0, calib.fy, calib.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
        },
    }


def write_intrinsics(path: Path, calib: Calibration) -> None:
    path.write_text(json.dumps(intrinsics(calib), indent=2) + "\n")


WRITERS = {"ply": write_ply, "pcd": write_pcd, "png": write_depth_png}
"""Per-frame formats → writer(path, frame) returning what it wrote (points or pixels)."""
