"""A `Frame` from any depth source's arrays (`Frame.from_arrays`), every size and value checked.

A tofcut camera's frames come from its taps; any other camera's (a Kinect, a RealSense, depth
maps on disk) come from here: range along the rays, depth (z) or points, with the pinhole
that gives their rays, an optional amplitude (the tracker's range noise grows as √B / A,
`tracker.noise`), validity and time. What it cannot use is a one-line `FrameInputError`.
"""

from __future__ import annotations

import math
import time

import numpy as np
import numpy.typing as npt

from tofcut._types import F64, B
from tofcut.driver.errors import FrameInputError
from tofcut.driver.frames import Frame
from tofcut.driver.intrinsics import Intrinsics, is_real_number, is_whole_number
from tofcut.driver.protocol import MAX_SENSOR_SIDE, FrameHeader

MAX_TIME_S = 2**63 / 1e6
"""Device times are microseconds below 2^63 (what rerun's nanosecond timelines hold)."""
MAX_SEQUENCE = 2**64
AGREE_REL = 1e-6
"""How far |xyz| and range_m, when both are given, may differ at a valid pixel (relative)."""


def _where(mask: B) -> str:
    """How many pixels of `mask` are set, and the first (row, column)."""
    v, u = np.argwhere(mask)[0]
    n = int(mask.sum())
    return (
        f"1 pixel, at row {v}, column {u}"
        if n == 1
        else f"{n} pixels, the first at row {v}, column {u}"
    )


def _numbers(name: str, value: npt.ArrayLike, shape: tuple[int, ...], source: str) -> F64:
    """`value` as a new float64 array of `shape`; `FrameInputError` if it is not one."""
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        raise FrameInputError(f"{name} is not an array of numbers") from None
    if a.dtype.kind not in "iuf":
        raise FrameInputError(f"{name} must be an array of numbers, not of {a.dtype}")
    if a.shape != shape:
        raise FrameInputError(f"{name} has shape {a.shape}, expected {shape} ({source})")
    return np.array(a, dtype=np.float64)


def _distances(name: str, a: F64) -> tuple[B, F64, str]:
    """Where `a` (range, depth or points) is finite, the distance it gives there (z for
    points; 0 elsewhere), and what a negative one is."""
    if name == "xyz":
        finite: B = np.logical_and.reduce(np.isfinite(a), axis=-1)
        z: F64 = np.where(finite, a[..., 2], 0.0)
        return finite, z, "points behind the camera (z < 0; x right, y down, z forward)"
    finite = np.isfinite(a)
    value: F64 = np.where(finite, a, 0.0)
    return finite, value, "negative values"


def frame_from_arrays(
    *,
    time_s: float,
    range_m: npt.ArrayLike | None = None,
    depth_m: npt.ArrayLike | None = None,
    xyz: npt.ArrayLike | None = None,
    intrinsics: Intrinsics | None = None,
    amplitude: npt.ArrayLike | None = None,
    intensity: npt.ArrayLike | None = None,
    valid: npt.ArrayLike | None = None,
    sequence: int = 0,
    host_time_ns: int | None = None,
) -> Frame:
    """What `Frame.from_arrays` does (its docstring says what each argument is)."""
    given = {
        name: a for name, a in (("range_m", range_m), ("depth_m", depth_m), ("xyz", xyz))
        if a is not None
    }  # fmt: skip
    if not given or (depth_m is not None and len(given) > 1):
        also = f", not {' and '.join(given)}" if given else ""
        raise FrameInputError(f"give range_m, depth_m or xyz (or range_m and xyz){also}")
    if intrinsics is not None and not isinstance(intrinsics, Intrinsics):
        raise FrameInputError(
            "intrinsics must be a tofcut.driver.intrinsics.Intrinsics "
            "(Intrinsics(...), .from_matrix(K, ...) or .from_json(...))"
        )
    if intrinsics is None and xyz is None:
        kind = "range_m" if range_m is not None else "depth_m"
        raise FrameInputError(f"{kind} needs intrinsics: they give each pixel's ray")
    if not is_real_number(time_s) or not 0 <= time_s < MAX_TIME_S:
        raise FrameInputError(f"time_s must be a finite number of seconds ≥ 0, not {time_s!r:.40}")
    if not is_whole_number(sequence) or not 0 <= sequence < MAX_SEQUENCE:
        raise FrameInputError(f"sequence must be a whole number ≥ 0, not {sequence!r:.40}")
    if host_time_ns is None:
        host_time_ns = time.time_ns()
    elif not is_whole_number(host_time_ns) or host_time_ns < 0:
        raise FrameInputError(f"host_time_ns must be a whole number ≥ 0, not {host_time_ns!r:.40}")

    if intrinsics is not None:
        h, w = intrinsics.height, intrinsics.width
        source = "height, width from the intrinsics"
    else:
        assert xyz is not None
        try:
            shape = np.shape(xyz)
        except ValueError:  # a ragged nest of lists
            raise FrameInputError("xyz is not an array of numbers") from None
        if len(shape) != 3 or shape[2] != 3:
            raise FrameInputError(f"xyz has shape {shape}, expected (height, width, 3)")
        h, w = shape[0], shape[1]
        if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
            raise FrameInputError(f"xyz is {w}x{h} pixels: each side must be 1..{MAX_SENSOR_SIDE}")
        source = "height, width of xyz"
    arrays = {
        name: _numbers(name, a, (h, w, 3) if name == "xyz" else (h, w), source)
        for name, a in given.items()
    }
    checked = {name: _distances(name, a) for name, a in arrays.items()}
    usable = np.logical_and.reduce([finite & (value > 0) for finite, value, _ in checked.values()])

    if valid is None:
        mask = usable
        for name, (_, value, negative_is) in checked.items():
            if (negative := value < 0).any():
                raise FrameInputError(
                    f"{name} has {negative_is} at {_where(negative)}; give valid to leave "
                    "such pixels out"
                )
    else:
        v = np.asarray(valid)
        if v.dtype != np.bool_ or v.shape != (h, w):
            raise FrameInputError(
                f"valid must be a boolean array of shape {(h, w)}, not {v.dtype} {v.shape}"
            )
        mask = v.copy()
        for name, (_, value, negative_is) in checked.items():
            if (negative := mask & (value < 0)).any():
                raise FrameInputError(
                    f"{name} has {negative_is} at valid pixels: {_where(negative)}"
                )
        if (unusable := mask & ~usable).any():
            what = " and ".join(
                "a point with z > 0" if name == "xyz" else f"a {name} > 0" for name in arrays
            )
            raise FrameInputError(
                f"valid marks pixels without {what} (not finite, or 0): {_where(unusable)}"
            )

    def weights(name: str, value: npt.ArrayLike) -> F64:
        a = _numbers(name, value, (h, w), source)
        ok = np.isfinite(a)
        if (negative := ok & (a < 0)).any():
            raise FrameInputError(f"{name} is negative at {_where(negative)}")
        if (missing := mask & ~ok).any():
            raise FrameInputError(f"{name} is not finite at valid pixels: {_where(missing)}")
        a[~ok] = 0.0
        return a

    amp = np.ones((h, w)) if amplitude is None else weights("amplitude", amplitude)
    if intensity is None:  # ambient light taken as even: the range noise goes as 1 / A
        level = float(np.median(amp[mask])) if mask.any() else 1.0
        bright = np.full((h, w), level if level > 0 else 1.0)
    else:
        bright = weights("intensity", intensity)

    if "xyz" in arrays:
        points = np.where(checked["xyz"][0][..., None], arrays["xyz"], 0.0)
        rng = np.linalg.norm(points, axis=-1)
        if "range_m" in arrays:
            rng_given = checked["range_m"][1]
            off = mask & (np.abs(rng - rng_given) > AGREE_REL * rng_given)
            if off.any():
                raise FrameInputError(
                    f"xyz and range_m disagree (|xyz| is not the range) at valid pixels: "
                    f"{_where(off)}"
                )
            rng = rng_given
    else:
        assert intrinsics is not None
        rays = intrinsics.rays()
        # a depth (z) over the unit ray's z is the range along it
        rng = checked["range_m"][1] if "range_m" in arrays else checked["depth_m"][1] / rays[..., 2]
        points = rays * rng[..., None]

    header = FrameHeader(
        sequence=int(sequence),
        device_time_us=round(time_s * 1e6),
        width=w,
        height=h,
        mod_code=0,
        integration=0,
        flags=0,
        temperature_c=math.nan,
        tap_interval_us=0,
        payload_size=0,
        payload_crc=0,
    )
    return Frame(
        header=header,
        host_time_ns=int(host_time_ns),
        phase=np.zeros((h, w)),
        amplitude=amp,
        intensity=bright,
        range=rng,
        valid=mask,
        xyz=points,
    )
