"""The whole driver through pyusb, against the emulated camera on an emulated bus."""

from __future__ import annotations

import errno

import numpy as np
import pytest
import usb.core

from tofcut.driver import (
    Camera,
    CameraConfig,
    CaptureReader,
    CaptureWriter,
    DeviceBusy,
    DeviceNotFound,
    DeviceTimeout,
    Register,
    RequestRejected,
    capture_metadata,
    list_cameras,
)
from tofcut.driver.protocol import PRODUCT, STATUS_FIFO_OVERFLOW, STATUS_STREAMING, Request
from tofcut.sim import EmulatedBackend, EmulatedCamera, TestPattern
from tofcut.sim.device import TRUTH_KEPT


class FakeClock:
    """A monotonic clock that only moves when the test says so."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def make_bus(*, width=32, height=24, realtime=False, serial=0x4000002F, clock=None):
    kwargs = {"monotonic": clock} if clock else {}
    emu = EmulatedCamera(
        TestPattern(width, height, seed=serial), serial=serial, realtime=realtime, **kwargs
    )
    return EmulatedBackend([emu]), emu


def test_pyusb_sees_the_emulated_camera_as_a_real_one():
    backend, _ = make_bus()
    dev = usb.core.find(idVendor=0x0852, idProduct=0x0074, backend=backend)
    assert dev is not None
    assert dev.serial_number == "4000002F"
    assert dev.product == PRODUCT
    assert dev.bcdDevice == 0x0104
    intf = dev[0][(0, 0)]
    assert intf.bInterfaceClass == 0xFF
    (ep,) = intf.endpoints()
    assert (ep.bEndpointAddress, ep.wMaxPacketSize) == (0x86, 512)


def test_discovery_by_serial_and_by_user_given_ids():
    a = EmulatedCamera(TestPattern(seed=1), serial=0x11111111, realtime=False)
    b = EmulatedCamera(TestPattern(seed=2), serial=0x22222222, realtime=False)
    backend = EmulatedBackend([a])
    backend.plug(b, vendor_id=0x1234, product_id=0x5678)
    assert [c.serial for c in list_cameras(backend=backend)] == ["11111111"]
    other = list_cameras(backend=backend, vendor_id=0x1234, product_id=0x5678)
    assert [c.serial for c in other] == ["22222222"]
    with Camera.open("22222222", backend=backend, vendor_id=0x1234, product_id=0x5678) as cam:
        assert cam.serial == "22222222"
    with pytest.raises(DeviceNotFound, match="serial 33333333"):
        Camera.open("33333333", backend=backend)


def test_info_and_calibration_are_read_and_checked():
    backend, emu = make_bus()
    with Camera.open(backend=backend) as cam:
        assert (cam.info.width, cam.info.height) == (32, 24)
        assert cam.calibration_block == emu.flash
        np.testing.assert_array_equal(
            cam.calibration.phase_offset_raw, emu.source.calibration.phase_offset_raw
        )
        assert cam.calibration.fx == pytest.approx(emu.source.calibration.fx)
        assert cam.temperature_c() == pytest.approx(36.5)


def test_configuration_round_trips_through_the_registers():
    backend, _ = make_bus()
    with Camera.open(backend=backend) as cam:
        assert cam.config == CameraConfig()
        wanted = CameraConfig.make(
            mod_freq_mhz=15, integration_ms=2.0, frame_rate=20, trigger_mode="software"
        )
        cam.configure(wanted)
        assert cam.config == wanted


@pytest.mark.parametrize(
    ("register", "value"),
    [
        (Register.MOD_FREQ, 3),  # unsupported code
        (Register.INTEGRATION, 256),
        (Register.TRIGGER_MODE, 7),
        (Register.STATUS, 0),  # read-only
        (0x42, 1),  # no such register
    ],
)
def test_invalid_writes_stall_and_the_camera_stays_usable(register, value):
    backend, _ = make_bus()
    with Camera.open(backend=backend) as cam:
        with pytest.raises(RequestRejected) as info:
            cam.write_register(register, value)
        assert info.value.errno == errno.EPIPE
        assert cam.read_register(Register.MOD_FREQ) == 1
        assert len(list(cam.raw_frames(count=2))) == 2


def test_unknown_requests_stall():
    backend, _ = make_bus()
    with Camera.open(backend=backend) as cam:
        with pytest.raises(RequestRejected):
            cam._usb.control_in(0x7F, 0, 0, 4)
        with pytest.raises(RequestRejected):
            cam._usb.control_in(Request.READ_FLASH, 10_000, 0, 64)


def test_a_stream_of_frames_arrives_with_no_loss():
    backend, emu = make_bus()
    with Camera.open(backend=backend) as cam:
        frames = list(cam.frames(count=60))
    seqs = [f.sequence for f in frames]
    assert seqs == list(range(60))
    assert cam.stats.lost == cam.stats.damaged == 0
    times = np.diff([f.device_time_us for f in frames])
    assert set(times.tolist()) == {20_000}  # 50 fps, the reset FRAME_PERIOD
    assert all(f.host_time_ns > 0 for f in frames)
    assert emu.frames_sent == 60
    # The emulator keeps only the newest frames' truth (a long run must not grow).
    assert emu.truth(59) is not None
    assert emu.truth(59 - TRUTH_KEPT) is None


def test_decoded_range_matches_the_source_truth():
    backend, emu = make_bus(width=48, height=36)
    with Camera.open(backend=backend) as cam:
        frame = next(cam.frames(count=1))
    truth = emu.truth(frame.sequence)
    still = np.abs(frame.range - truth) < 0.05  # the moving sphere's edge moves between taps
    assert still.mean() > 0.95
    # 4-count noise on a 2000-count amplitude: σ_r ≈ c/(4πf) · σ/(√2·A) ≈ 1 mm
    assert np.std((frame.range - truth)[still]) < 0.005


def test_small_buffer_reads_reassemble_frames():
    backend, _ = make_bus()
    with Camera.open(backend=backend, read_size=512) as cam:
        frames = list(cam.raw_frames(count=10))
    assert [f.sequence for f in frames] == list(range(10))
    assert cam.stats.lost == cam.stats.damaged == 0


def test_frames_that_are_whole_packets_end_with_a_zero_length_packet():
    backend, _ = make_bus(width=8, height=7)  # 64 + 4·8·7·2 = 512 bytes: one whole packet
    with Camera.open(backend=backend) as cam:
        assert cam.info.frame_size == 512
        frames = list(cam.raw_frames(count=5))
    assert [f.sequence for f in frames] == list(range(5))


@pytest.mark.parametrize("kind", ["payload", "header", "truncate"])
def test_damaged_frames_are_skipped_and_the_stream_goes_on(kind):
    backend, emu = make_bus()
    with Camera.open(backend=backend) as cam:
        first = list(cam.raw_frames(count=3))
        emu.damage_next(kind, count=2)
        rest = list(cam.raw_frames(count=5))
    seqs = [f.sequence for f in first + rest]
    assert seqs == [0, 1, 2, 5, 6, 7, 8, 9]
    assert cam.stats.lost == 2
    assert list(cam.stats.gaps) == [(3, 4)]
    assert cam.stats.damaged >= 1


def test_a_second_program_gets_busy():
    backend, _ = make_bus()
    with Camera.open(backend=backend), pytest.raises(DeviceBusy, match="another program"):
        Camera.open(backend=backend)


def test_reads_time_out_when_not_streaming_and_sequence_survives_a_restart():
    backend, _ = make_bus()
    with Camera.open(backend=backend) as cam:
        with pytest.raises(DeviceTimeout):
            cam.read_raw(timeout_ms=50)
        assert [f.sequence for f in cam.raw_frames(count=3)] == [0, 1, 2]
        cam.stop()
        with pytest.raises(DeviceTimeout):
            cam.read_raw(timeout_ms=50)
        assert [f.sequence for f in cam.raw_frames(count=2)] == [3, 4]


def test_software_trigger_takes_one_frame_each():
    backend, _ = make_bus()
    with Camera.open(backend=backend) as cam:
        cam.configure(CameraConfig.make(trigger_mode="software"))
        cam.start()
        with pytest.raises(DeviceTimeout):
            cam.read_raw(timeout_ms=50)
        cam.trigger()
        cam.trigger()
        assert [cam.read_raw().sequence, cam.read_raw().sequence] == [0, 1]
        with pytest.raises(DeviceTimeout):
            cam.read_raw(timeout_ms=50)


def test_real_time_pacing_and_fifo_overflow_leave_a_counted_gap():
    clock = FakeClock()
    backend, emu = make_bus(realtime=True, clock=clock)
    with Camera.open(backend=backend) as cam:
        cam.start()
        clock.t += 0.0205  # the first frame's four taps (4 × 3.5 ms) are done
        assert cam.read_raw().sequence == 0
        assert cam.read_register(Register.STATUS) == STATUS_STREAMING
        clock.t += 1.0  # the host looks away for a second: 50 frames are taken
        got = [cam.read_raw().sequence for _ in range(4)]
        clock.t += 0.04  # the next frame after the overflow finishes its taps
        got.append(cam.read_raw().sequence)
        assert got[:4] == [1, 2, 3, 4]  # the FIFO kept the oldest four
        status = cam.read_register(Register.STATUS)
        assert status & STATUS_FIFO_OVERFLOW
        assert not cam.read_register(Register.STATUS) & STATUS_FIFO_OVERFLOW  # read clears
    assert got[4] > 5
    assert cam.stats.lost == got[4] - 5
    assert cam.stats.device_dropped_flags == 1
    assert emu.frames_dropped == cam.stats.lost


def test_a_capture_replays_to_identical_frames(tmp_path):
    backend, _ = make_bus()
    path = tmp_path / "run.tofcap"
    with Camera.open(backend=backend) as cam:
        regs = {r.name: cam.read_register(r) for r in (Register.MOD_FREQ, Register.INTEGRATION)}
        meta = capture_metadata(cam.info, regs)
        live = []
        with CaptureWriter(path, meta, cam.calibration_block) as writer:
            for raw in cam.raw_frames(count=12):
                writer.write(raw)
                live.append(cam.demodulate(raw))
    reader = CaptureReader(path)
    replayed = list(reader.frames())
    assert len(reader) == 12
    assert [f.sequence for f in replayed] == [f.sequence for f in live]
    for a, b in zip(live, replayed, strict=True):
        assert a.header == b.header
        assert a.host_time_ns == b.host_time_ns
        for name in ("phase", "amplitude", "intensity", "range", "valid", "xyz"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_a_capture_cut_short_replays_up_to_its_last_whole_record(tmp_path):
    backend, _ = make_bus()
    path = tmp_path / "run.tofcap"
    with Camera.open(backend=backend) as cam:
        meta = capture_metadata(cam.info, {})
        with CaptureWriter(path, meta, cam.calibration_block) as writer:
            for raw in cam.raw_frames(count=5):
                writer.write(raw)
    data = path.read_bytes()
    path.write_bytes(data[:-1000])  # the recorder was killed inside the last record
    reader = CaptureReader(path)
    assert [f.sequence for f in reader.raw_frames()] == [0, 1, 2, 3]
    assert reader.truncated_bytes == 8 + cam.info.frame_size - 1000
    assert reader.stats.damaged == 0
