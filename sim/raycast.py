"""Casting the pixel rays into a scene: nearest hit per ray, vectorised, culled by windows.

Results go into `Hits` buffers (range, |cos incidence|, albedo, surface id). Surface ids:
objects keep their id (≥ 1); background surfaces are −1, −2, … so depth edges between
background pieces (belt against floor) are found too; labels clip them to 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tofcut._types import F64, I32, B
from tofcut.sim.geometry import Pose
from tofcut.sim.shapes import Shape


@dataclass(frozen=True, eq=False)
class Hits:
    """Nearest hit of a set of rays: range, |cos|, albedo, surface id (arrays of one shape)."""

    range: F64
    cos: F64
    albedo: F64
    sid: I32

    def copy(self) -> Hits:
        """Fresh buffers to cast more solids into."""
        return Hits(self.range.copy(), self.cos.copy(), self.albedo.copy(), self.sid.copy())

    def take(self, index: tuple[npt.NDArray[np.intp], ...]) -> Hits:
        """The hits at some positions (fancy index: a copy)."""
        return Hits(self.range[index], self.cos[index], self.albedo[index], self.sid[index])


@dataclass(frozen=True, eq=False)
class Placed:
    """One solid at the times of a frame: camera-from-local pose per time, and its window."""

    shape: Shape
    poses: tuple[Pose, ...]
    sid: int
    albedo: float
    window: tuple[int, int, int, int]
    """Pixel rows and columns (v0, v1, u0, u1) that can see it at any of the times."""


def hit_local(shape: Shape, pose: Pose, rays: F64) -> tuple[F64, F64]:
    """Cast camera-frame rays (3, N) from the camera centre at a posed solid."""
    rt = pose.rotation.T
    return shape.hit(-(rt @ pose.translation), rt @ rays)


def cast_all(solids: list[tuple[Shape, Pose, int, float]], rays: F64) -> Hits:
    """Nearest hit of rays (3, …) among posed solids (shape, pose, sid, albedo); no culling."""
    flat = rays.reshape(3, -1)
    n = flat.shape[1]
    out = Hits(np.full(n, np.inf), np.zeros(n), np.zeros(n), np.zeros(n, np.int32))
    for shape, pose, sid, albedo in solids:
        t, cos = hit_local(shape, pose, flat)
        m = t < out.range
        out.range[m] = t[m]
        out.cos[m] = cos[m]
        out.albedo[m] = albedo
        out.sid[m] = sid
    shape_ = rays.shape[1:]
    return Hits(
        out.range.reshape(shape_), out.cos.reshape(shape_), out.albedo.reshape(shape_),
        out.sid.reshape(shape_),
    )  # fmt: skip


def cast_windows(base: Hits, placed: list[Placed], k: int, rays: F64) -> Hits:
    """Pixel-centre hits at time index k: the background plus each solid cast in its window."""
    out = base.copy()
    for p in placed:
        v0, v1, u0, u1 = p.window
        block = rays[:, v0:v1, u0:u1]
        t, cos = hit_local(p.shape, p.poses[k], block.reshape(3, -1))
        t = t.reshape(block.shape[1:])
        r = out.range[v0:v1, u0:u1]
        m = t < r
        if not m.any():
            continue
        r[m] = t[m]
        out.cos[v0:v1, u0:u1][m] = cos.reshape(t.shape)[m]
        out.albedo[v0:v1, u0:u1][m] = p.albedo
        out.sid[v0:v1, u0:u1][m] = p.sid
    return out


def cast_samples(
    base: Hits, placed: list[Placed], k: int, rays: F64, rows: npt.NDArray[np.intp],
    cols: npt.NDArray[np.intp],
) -> Hits:  # fmt: skip
    """Sub-pixel hits at time index k for chosen pixels: rays (3, M, S), base buffers (M, S)."""
    out = base.copy()
    for p in placed:
        v0, v1, u0, u1 = p.window
        idx = np.flatnonzero((rows >= v0) & (rows < v1) & (cols >= u0) & (cols < u1))
        if idx.size == 0:
            continue
        sel = rays[:, idx]
        t, cos = hit_local(p.shape, p.poses[k], sel.reshape(3, -1))
        t = t.reshape(sel.shape[1:])
        r = out.range[idx]
        m = t < r
        if not m.any():
            continue
        out.range[idx] = np.where(m, t, r)
        out.cos[idx] = np.where(m, cos.reshape(t.shape), out.cos[idx])
        out.albedo[idx] = np.where(m, p.albedo, out.albedo[idx])
        out.sid[idx] = np.where(m, p.sid, out.sid[idx])
    return out


def depth_edges(hits: Hits, jump_m: float) -> B:
    """Pixels next to a change of surface or a range step, grown by one pixel each way."""
    sid, r = hits.sid, hits.range
    with np.errstate(invalid="ignore"):
        dh = (sid[:, 1:] != sid[:, :-1]) | (np.abs(r[:, 1:] - r[:, :-1]) > jump_m)
        dv = (sid[1:] != sid[:-1]) | (np.abs(r[1:] - r[:-1]) > jump_m)
    e = np.zeros(sid.shape, bool)
    e[:, 1:] |= dh
    e[:, :-1] |= dh
    e[1:] |= dv
    e[:-1] |= dv
    g = e.copy()
    g[1:] |= e[:-1]
    g[:-1] |= e[1:]
    out = g.copy()
    out[:, 1:] |= g[:, :-1]
    out[:, :-1] |= g[:, 1:]
    return out
