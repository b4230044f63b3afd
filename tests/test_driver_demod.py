"""The fast demodulation against spec §7 as written (`demodulate_reference`)."""

from __future__ import annotations

import numpy as np
import pytest

from tofcut.driver.demod import Optics, _range_scale, demodulate, demodulate_reference
from tofcut.driver.frames import RawFrame
from tofcut.driver.protocol import MAX_COUNT, MOD_FREQ_MHZ, FrameHeader
from tofcut.sim.catalog import open_scene
from tofcut.sim.preview import scene_exposure

FIELDS = ("phase", "amplitude", "intensity", "range", "xyz")


def _raw(taps: np.ndarray, mod_code: int) -> RawFrame:
    h, w = taps.shape[1:]
    header = FrameHeader(
        sequence=0, device_time_us=0, width=w, height=h, mod_code=mod_code, integration=30,
        flags=0, temperature_c=30.0, tap_interval_us=3500, payload_size=taps.nbytes, payload_crc=0,
    )  # fmt: skip
    return RawFrame(header=header, taps=taps, wire=b"", host_time_ns=0)


def _assert_same(raw: RawFrame, optics: Optics, threshold: float) -> None:
    fast = demodulate(raw, optics, threshold)
    ref = demodulate_reference(raw, optics, threshold)
    for name in FIELDS:
        got, want = getattr(fast, name), getattr(ref, name)
        assert got.dtype == np.float64, name
        assert got.shape == want.shape, name
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9, err_msg=name)
    np.testing.assert_array_equal(fast.valid, ref.valid)
    assert fast.xyz.flags.c_contiguous
    assert (fast.phase >= 0).all()
    assert (fast.phase < 2 * np.pi).all()


def test_fast_path_equals_the_reference_on_an_emulated_frame():
    source = open_scene("conveyor", 0)
    exposure = scene_exposure(source, 0.0)
    taps = source.render(exposure).taps
    _assert_same(_raw(taps, exposure.mod_code), Optics.from_calibration(source.calibration), 0.0)


@pytest.mark.parametrize("mod_code", sorted(MOD_FREQ_MHZ))
@pytest.mark.parametrize("threshold", [0.0, 200.0])
def test_fast_path_equals_the_reference_on_random_taps(mod_code, threshold):
    """Every quadrant, zero signal (s = c = 0), saturated taps and offsets beyond ±π."""
    rng = np.random.default_rng(mod_code)
    source = open_scene("conveyor", 0)
    calib = source.calibration
    h, w = calib.height, calib.width
    taps = rng.integers(0, MAX_COUNT + 1, (4, h, w)).astype(np.uint16)
    taps[:, :4, :] = 5000  # s = c = 0
    taps[0, 4, :8] = MAX_COUNT
    optics = Optics.from_calibration(calib)
    wide = Optics(optics.rays, rng.uniform(-3.2, 3.2, (h, w)), 0.05)
    for opt in (optics, wide):
        _assert_same(_raw(taps, mod_code), opt, threshold)


def test_counts_above_fourteen_bits_are_invalid_pixels_not_nan():
    """A tap above the sensor's 14 bits (the wire's u16 allows it) is held at full scale: the
    pixel is invalid, its amplitude finite, and nothing overflows (no RuntimeWarning)."""
    calib = open_scene("conveyor", 0).calibration
    taps = np.full((4, calib.height, calib.width), 5000, np.uint16)
    taps[1, 0, :3] = 65535
    taps[3, 0, :3] = 0
    taps[0, 1, 0] = MAX_COUNT + 1
    with np.errstate(all="raise"):
        frame = demodulate(_raw(taps, sorted(MOD_FREQ_MHZ)[0]), Optics.from_calibration(calib))
    assert np.isfinite(frame.amplitude).all()
    assert not frame.valid[0, :3].any()
    assert not frame.valid[1, 0]
    assert frame.valid[2:].all()


def _numpy_demodulate(raw: RawFrame, optics: Optics, amplitude_threshold: float) -> dict:
    """`demodulate` as it was in numpy before its per-pixel arithmetic was compiled
    (`tofcut.driver.demod_kernels`): the compiled one must give the same bits."""
    a0, a1, a2, a3 = np.minimum(raw.taps, MAX_COUNT).astype(np.int32)
    s = a3 - a1
    nc = a2 - a0
    phase = np.arctan2(s, nc, dtype=np.float64)
    np.subtract(np.pi, phase, out=phase)
    squares = s * s
    squares += nc * nc
    phase[squares == 0] = 0.0
    amplitude = np.sqrt(squares, dtype=np.float64)
    amplitude *= 0.5
    total = a0 + a1
    total += a2
    total += a3
    intensity = np.multiply(total, 0.25, dtype=np.float64)
    rng = phase - optics.wrapped_offset
    rng += 2.0 * np.pi * (rng < 0.0)
    rng *= _range_scale(raw)
    rng -= optics.distance_offset_m
    valid = raw.taps.max(axis=0) < MAX_COUNT
    if amplitude_threshold > 0.0:
        valid &= amplitude >= amplitude_threshold
    xyz = np.empty((*rng.shape, 3))
    np.multiply(optics.ray_planes, rng, out=np.moveaxis(xyz, -1, 0))
    return {"phase": phase, "amplitude": amplitude, "intensity": intensity, "range": rng,
            "valid": valid, "xyz": xyz}  # fmt: skip


@pytest.mark.parametrize("threshold", [0.0, 200.0])
def test_compiled_demodulation_gives_the_numpy_bits(threshold):
    """Bit for bit (signs of zero included) what the numpy expressions gave, on an emulated
    frame as parsed off the wire (read-only taps) and on random taps of every value a u16
    holds, zero signal among them, with offsets beyond ±π."""
    source = open_scene("conveyor", 0)
    exposure = scene_exposure(source, 0.0)
    optics = Optics.from_calibration(source.calibration)
    h, w = optics.phase_offset.shape
    taps = source.render(exposure).taps
    wire = np.frombuffer(taps.astype("<u2").tobytes(), "<u2").reshape(taps.shape)
    rng = np.random.default_rng(7)
    noisy = rng.integers(0, 65536, (4, h, w)).astype(np.uint16)
    noisy[:, :4, :] = 5000  # s = c = 0
    wide = Optics(optics.rays, rng.uniform(-3.2, 3.2, (h, w)), 0.05)
    for raw, opt in [
        (_raw(wire, exposure.mod_code), optics),
        (_raw(noisy, exposure.mod_code), optics),
        (_raw(noisy, sorted(MOD_FREQ_MHZ)[-1]), wide),
    ]:
        frame = demodulate(raw, opt, threshold)
        for name, want in _numpy_demodulate(raw, opt, threshold).items():
            got = getattr(frame, name)
            assert got.dtype == want.dtype, name
            assert got.flags.c_contiguous, name
            np.testing.assert_array_equal(got, want, err_msg=name)
            assert np.array_equal(np.signbit(got), np.signbit(want)), name
