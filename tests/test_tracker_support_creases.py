"""The support energy's crease stage: objects that touch the target are cut off at the
concave creases where their surfaces meet it, and an object's own convex edges are not."""

from __future__ import annotations

import numpy as np

from tofcut.tools.experiments.reproduce import iou
from tofcut.tracker.paper import support as sp
from tofcut.tracker.paper.segment import Energy, Target, segment_arrays

H, W = 72, 96
F = 80.0


def camera_rays(tilt_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit rays per pixel in the camera frame (x right, y down, z forward), and the
    rotation that takes camera vectors to a world frame whose z is up, for a camera looking
    down at `tilt_deg` along world +y."""
    v, u = np.mgrid[0:H, 0:W]
    rays = np.stack([(u - W / 2) / F, (v - H / 2) / F, np.ones((H, W))], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    t = np.deg2rad(tilt_deg)
    forward = np.array([0.0, np.cos(t), -np.sin(t)])
    down = np.array([0.0, -np.sin(t), -np.cos(t)])
    right = np.cross(down, forward)
    return rays, np.stack([right, down, forward], axis=1)


def cast(rays_world: np.ndarray, eye: np.ndarray, boxes: list[tuple[np.ndarray, np.ndarray]]):
    """Distance along each ray to the floor z = 0 or the nearest axis-aligned box (lo, hi),
    and the index of what was hit (0 the floor, i + 1 box i)."""
    dist = np.where(rays_world[..., 2] < 0, -eye[2] / np.minimum(rays_world[..., 2], -1e-9), 1e9)
    label = np.zeros(dist.shape, np.int32)
    inv = 1.0 / np.where(rays_world == 0.0, 1e-12, rays_world)
    for i, (lo, hi) in enumerate(boxes):
        a, b = (lo - eye) * inv, (hi - eye) * inv
        near = np.minimum(a, b).max(axis=-1)
        far = np.maximum(a, b).min(axis=-1)
        hit = (near <= far) & (near > 0) & (near < dist)
        dist = np.where(hit, near, dist)
        label[hit] = i + 1
    return dist, label


def boxes_on_a_floor(behind_height: float | None, noise: float, seed: int = 0):
    """A 24 × 24 × 12 cm box on a floor seen from 1.4 m at 45°, and a 24 cm wide box of
    `behind_height` (None: none) touching it behind, its front face rising above the
    target's top; range noise `noise`, the same intensity everywhere. Returns the frame's
    arrays, the labels, and the target's centroid (camera frame) and extent."""
    rays, cam_to_world = camera_rays(45.0)
    eye = np.array([0.0, -1.0, 1.0])
    target = (np.array([-0.12, -0.12, 0.0]), np.array([0.12, 0.12, 0.12]))
    boxes = [target]
    if behind_height is not None:
        boxes.append((np.array([-0.12, 0.12, 0.0]), np.array([0.12, 0.36, behind_height])))
    dist, labels = cast(rays @ cam_to_world.T, eye, boxes)
    dist = dist + np.random.default_rng(seed).normal(0.0, noise, dist.shape)
    xyz = rays * dist[..., None]
    centre_world = np.array([0.0, 0.0, 0.06])
    centre = (centre_world - eye) @ cam_to_world
    extent = float(np.linalg.norm([0.24, 0.24, 0.12])) / 2.0
    return np.full((H, W), 1000.0), xyz, np.ones((H, W), bool), labels, centre, extent


def test_concavity_is_positive_over_a_ridge_and_negative_in_a_valley():
    rays, cam_to_world = camera_rays(45.0)
    eye = np.array([0.0, -1.0, 1.0])
    world = rays @ cam_to_world.T
    dist = -eye[2] / world[..., 2]  # the floor
    xyz = rays * dist[..., None]
    # bend the floor along the image's middle row: up towards the camera (a ridge seen from
    # above, convex) or away from it (a valley, concave)
    v = np.arange(H)[:, None] * np.ones((1, W))
    for sign in (1.0, -1.0):
        fold = xyz.copy()
        fold[..., 2] += sign * 0.004 * np.abs(v - H / 2)  # 4 mm a row farther or nearer
        mean, normal = sp.surface_normals(fold, np.ones((H, W), bool))
        c = sp.concavity(mean, normal)[1]  # down the image, across the fold
        across = c[H // 2 - 2 : H // 2 + 2, 10:-10]
        flat = c[10:20, 10:-10]
        assert np.all(sign * across > 0.02), sign
        assert np.all(np.abs(flat) < 0.01)


def test_a_box_touching_the_target_is_cut_off_at_the_crease_given_the_extent():
    intensity, xyz, valid, labels, centre, extent = boxes_on_a_floor(0.24, 0.003)
    truth = labels == 1
    rows, cols = np.nonzero(truth)
    seed = (int(cols.mean()), int(rows.mean()))
    assert truth[seed[1], seed[0]]
    bare = segment_arrays(intensity, xyz, valid, Target(pixel=seed), Energy.SUPPORT)
    # without an extent the energy has no size to weigh against: the box behind, joined in
    # range and above the floor, comes with the target
    assert np.mean(bare.mask[labels == 2]) > 0.8
    given = Target(pixel=seed, point=tuple(float(c) for c in centre), extent_m=extent)
    ours = segment_arrays(intensity, xyz, valid, given, Energy.SUPPORT)
    assert iou(ours.mask, truth) > 0.85
    assert np.mean(ours.mask[labels == 2]) < 0.1


def test_apart_at_creases_keeps_what_joins_the_seed_at_convex_edges():
    # the box alone on the floor: the crease stage keeps its faces, which meet at convex
    # edges, and the seed's part is the box
    _, xyz, _, labels, centre, extent = boxes_on_a_floor(None, 0.003)
    truth = labels == 1
    rows, cols = np.nonzero(truth)
    seed = (int(cols.mean()), int(rows.mean()))
    kept = sp.apart_at_creases(truth, xyz, seed, centre, extent, 0.05, 0.25, 8.0, 0.5)
    assert np.array_equal(kept, truth)
