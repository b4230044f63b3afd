"""The renderer as a sensor: noise, 1/r², wrapping, saturation, lens and phase offsets, mixed
pixels and tap timing, checked by decoding its taps with the driver."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from tofcut.driver.calibration import Calibration, distort, pixel_rays
from tofcut.driver.demod import Optics, demodulate
from tofcut.driver.frames import Frame, RawFrame
from tofcut.driver.protocol import MAX_COUNT, FrameHeader, mod_freq_hz, unambiguous_range_m
from tofcut.sim.lens import rays_at
from tofcut.sim.raycast import cast_all
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene import part_poses
from tofcut.sim.scene_file import parse_scene
from tofcut.sim.sensor import predicted_range_sigma
from tofcut.sim.source import Exposure

WALL = """
name = "wall"
duration_s = 10.0
[camera]
position = [0.0, 0.0, 0.0]
look_at = [0.0, 1.0, 0.0]
mod_code = {mod_code}
[[surface]]
shape = "plane"
position = [0.0, {distance}, 0.0]
rotation_deg = [90, 0, 0]
albedo = {albedo}
"""


def source_from(text: str, seed: int = 0) -> SceneSource:
    """A renderer for a scene given as TOML text."""
    return SceneSource(parse_scene(tomllib.loads(text)), seed)


def wall(
    distance: float, mod_code: int = 1, albedo: float = 0.5, extra: str = "", seed: int = 0
) -> SceneSource:
    """A wall square to the optical axis `distance` metres away (plus any extra TOML)."""
    return source_from(
        WALL.format(distance=distance, mod_code=mod_code, albedo=albedo) + extra, seed
    )


def exposure(
    sequence: int = 0, t0: float = 0.0, mod_code: int = 1, interval: float = 3.5e-3
) -> Exposure:
    """A frame with the reset integration time (3.3 ms)."""
    return Exposure(sequence, t0, interval, 3.3e-3, mod_code)


def decode(taps: np.ndarray, calib: Calibration, mod_code: int = 1) -> Frame:
    """Demodulate taps with the driver, no USB involved."""
    h, w = taps.shape[1:]
    header = FrameHeader(
        sequence=0, device_time_us=0, width=w, height=h, mod_code=mod_code, integration=30,
        flags=0, temperature_c=30.0, tap_interval_us=3500, payload_size=taps.nbytes, payload_crc=0,
    )  # fmt: skip
    raw = RawFrame(header=header, taps=taps, wire=b"", host_time_ns=0)
    return demodulate(raw, Optics.from_calibration(calib))


def amplitude_intensity(means: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A and B of mean taps by spec §7."""
    a0, a1, a2, a3 = means
    return 0.5 * np.hypot(a3 - a1, a0 - a2), means.mean(axis=0)


CENTRE = (slice(52, 92), slice(68, 108))


def test_decoded_range_spread_matches_the_noise_model():
    src = wall(1.5)
    frames = [decode(src.render(exposure(i)).taps, src.calibration) for i in range(120)]
    ranges = np.stack([f.range for f in frames])[:, CENTRE[0], CENTRE[1]]
    means, truth = src.mean_taps(exposure(0))
    amp, inten = amplitude_intensity(means)
    predicted = predicted_range_sigma(src.scene.sensor, inten, amp, mod_freq_hz(1))[CENTRE]
    spread = ranges.std(axis=0, ddof=1)
    ratio = np.median(spread / predicted)
    assert 0.93 < ratio < 1.07, ratio
    assert 2e-3 < float(np.median(predicted)) < 2e-2  # a SwissRanger's few millimetres
    bias = ranges.mean(axis=0) - truth.range[CENTRE]
    z = bias / (predicted / math.sqrt(len(frames)))
    assert abs(float(np.mean(z))) < 0.3
    assert float(np.mean(np.abs(z) < 3.0)) > 0.98


def test_amplitude_falls_as_inverse_square():
    amps = {}
    for d in (1.0, 2.0, 3.0):
        src = wall(d)
        frames = [decode(src.render(exposure(i)).taps, src.calibration) for i in range(4)]
        amps[d] = float(np.mean([f.amplitude[CENTRE] for f in frames]))
    assert amps[1.0] / amps[2.0] == pytest.approx(4.0, rel=0.01)
    assert amps[1.0] / amps[3.0] == pytest.approx(9.0, rel=0.02)


def test_amplitude_scales_with_albedo_and_integration():
    dim, bright = wall(1.5, albedo=0.25), wall(1.5, albedo=0.5)
    a_dim = amplitude_intensity(dim.mean_taps(exposure())[0])[0]
    a_bright = amplitude_intensity(bright.mean_taps(exposure())[0])[0]
    assert np.allclose(a_bright / a_dim, 2.0)
    long = Exposure(0, 0.0, 7.0e-3, 6.6e-3, 1)
    a_long = amplitude_intensity(bright.mean_taps(long)[0])[0]
    assert np.allclose(a_long / a_bright, 2.0)


def test_a_surface_beyond_the_unambiguous_range_folds_back():
    src = wall(3.0, mod_code=5)
    wrapped = decode(src.render(exposure(mod_code=5)).taps, src.calibration, mod_code=5)
    assert unambiguous_range_m(5) < 2.5
    assert np.median(wrapped.range[CENTRE]) == pytest.approx(3.0 - unambiguous_range_m(5), abs=0.01)
    direct = decode(src.render(exposure(mod_code=1)).taps, src.calibration, mod_code=1)
    assert np.median(direct.range[CENTRE]) == pytest.approx(3.0, abs=0.01)


SPHERE = """
[[object]]
name = "ball"
shape = "sphere"
radius = 0.08
position = [0.0, {y}, 0.0]
albedo = {albedo}
"""


def test_a_saturated_pixel_is_flagged():
    src = wall(2.0, extra=SPHERE.format(y=0.35, albedo=0.9))
    rendered = src.render(exposure())
    frame = decode(rendered.taps, src.calibration)
    ball = rendered.truth.labels == 1
    assert ball.sum() > 100
    assert (rendered.taps.max(axis=0)[ball] == MAX_COUNT).mean() > 0.9
    assert not frame.valid[ball].mean() > 0.1
    assert frame.valid[~ball].mean() > 0.95


def test_the_driver_undoes_phase_offsets_and_distortion():
    src = wall(1.5)
    calib = src.calibration
    assert abs(calib.k1) > 0.1
    assert np.std(calib.phase_offset) > 0.02
    assert calib.distance_offset_m
    taps = src.render(exposure()).taps
    frame = decode(taps, calib)
    corners = (slice(0, 20), slice(0, 20))
    assert np.median(np.abs(frame.xyz[..., 2] - 1.5)) < 0.005
    assert abs(np.median(frame.xyz[..., 2][corners]) - 1.5) < 0.004
    naive = Calibration(calib.width, calib.height, 1, calib.fx, calib.fy, calib.cx, calib.cy)
    wrong = decode(taps, naive)
    assert np.median(np.abs(wrong.xyz[..., 2][corners] - 1.5)) > 0.03
    assert np.std(wrong.range - frame.range) > 0.015  # the phase offsets, a few cm of range


def test_our_rays_invert_the_drivers_lens_model():
    calib = wall(1.5).calibration
    v, u = np.mgrid[0 : calib.height, 0 : calib.width].astype(np.float64)
    rays = rays_at(calib, u, v)
    xd, yd = distort(calib, rays[0] / rays[2], rays[1] / rays[2])
    assert np.max(np.abs(xd * calib.fx + calib.cx - u)) < 1e-9
    assert np.max(np.abs(yd * calib.fy + calib.cy - v)) < 1e-9
    assert np.max(np.abs(np.moveaxis(rays, 0, -1) - pixel_rays(calib))) < 1e-9


def test_depth_edges_make_mixed_pixels():
    src = wall(2.0, extra=SPHERE.format(y=1.0, albedo=0.5))
    means, truth = src.mean_taps(exposure())
    a0, a1, a2, a3 = means
    phase = np.mod(np.arctan2(a3 - a1, a0 - a2) - src.calibration.phase_offset, 2 * math.pi)
    rng = phase * 299_792_458.0 / (4 * math.pi * mod_freq_hz(1)) - src.calibration.distance_offset_m
    between = (rng > 1.0) & (rng < 1.9)
    ball = truth.labels == 1
    edge = np.zeros_like(ball)
    for axis in (0, 1):
        for shift in (1, -1):
            edge |= ball ^ np.roll(ball, shift, axis=axis)
    assert between.sum() > 10
    assert edge[between].all()  # only on the silhouette, never inside a surface
    near = edge.copy()
    for axis in (0, 1):
        for shift in (1, -1):
            near |= np.roll(edge, shift, axis=axis)
    assert np.abs(rng[~near] - truth.range[~near]).max() < 1e-3  # smooth surfaces stay exact


MOVING = """
[sensor]
supersample = 1   # no mixed pixels: which pixels are edges depends on the frame's mid time
[[object]]
name = "slider"
shape = "box"
size = [0.2, 0.2, 0.2]
position = [0.0, 1.2, 0.0]
motion = "linear"
velocity = [4.0, 0.0, 0.0]
"""


def test_each_tap_sees_the_scene_at_its_own_time():
    src = wall(2.0, extra=MOVING)
    exp = exposure(t0=0.01)
    means = src.mean_taps(exp)[0]
    for k in range(4):
        at_k = Exposure(0, exp.t0_s + k * exp.tap_interval_s, 0.0, exp.integration_s, 1)
        assert np.allclose(means[k], src.mean_taps(at_k)[0][k])
    frozen = Exposure(0, exp.t0_s, 0.0, exp.integration_s, 1)
    assert not np.allclose(means[3], src.mean_taps(frozen)[0][3])


def test_rendering_is_deterministic_per_seed_and_sequence():
    a, b = wall(1.5, seed=3), wall(1.5, seed=3)
    for i in range(3):
        a.render(exposure(i))
    assert np.array_equal(a.render(exposure(7)).taps, b.render(exposure(7)).taps)
    assert not np.array_equal(a.render(exposure(7)).taps, a.render(exposure(8)).taps)
    c = wall(1.5, seed=4)
    assert not np.array_equal(a.render(exposure(7)).taps, c.render(exposure(7)).taps)
    assert not np.array_equal(a.calibration.phase_offset_raw, c.calibration.phase_offset_raw)


@pytest.mark.parametrize("t", [0.0, 3.3, 7.1, 12.9])
def test_culling_by_windows_changes_nothing(t):
    from tofcut.sim.catalog import open_scene

    src = open_scene("conveyor")
    scene = src.scene
    cam = scene.camera_from_world
    solids = [
        (s.shape, cam.compose(s.pose), -(i + 1), s.albedo) for i, s in enumerate(scene.surfaces)
    ]
    for obj in scene.objects:
        for part, pose in zip(obj.parts, part_poses(obj, t, scene.belt, cam), strict=True):
            solids.append((part.shape, pose, obj.id, part.albedo))
    full = cast_all(solids, src._rays.centre)
    truth = src.truth_at(t)
    assert np.array_equal(np.maximum(full.sid, 0), truth.labels)
    assert np.allclose(full.range, truth.range, rtol=1e-6)
    assert (truth.labels > 0).sum() > 1000
