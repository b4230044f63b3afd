"""The conveyor link over a real pseudo-terminal: the project's client (pymodbus) against the
emulated controller, faults on the line, and both ends checked against pymodbus's own."""

from __future__ import annotations

import asyncio
import os
import random
import socket
import threading
import time
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
import pytest
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusIOException
from pymodbus.framer import FramerType
from pymodbus.framer.rtu import FramerRTU
from pymodbus.server import ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from tofcut.driver.conveyor.config import LINK_RANGES, LinkSettings, RegisterMap
from tofcut.driver.conveyor.link import COMMANDS_KEPT, ConveyorClient
from tofcut.driver.errors import LinkError
from tofcut.sim.conveyor import EmulatedConveyor
from tofcut.sim.modbus_rtu import crc16
from tofcut.testing import ConveyorRig
from tofcut.tracker.belt_prior import belt_velocity_prior

WAIT_S = 5.0
"""Upper bound of every wait; each returns as soon as its condition holds."""
FAST_SETTINGS = dict(
    parity="N",  # a pseudo-terminal refuses parity settings
    timeout_s=0.1,
    retries=2,
    poll_hz=200.0,
    heartbeat_s=0.0,  # off unless a test wants it, so injected faults hit polls only
    reopen_s=0.02,
)
FAST_LINK = LinkSettings(**FAST_SETTINGS)
DIRECTION = np.array([0.8, 0.0, 0.6])


@pytest.fixture
def pty_line(tofcut_conveyor_factory, tmp_path):
    """Start the emulated controller on a pty (opened through a symlink, like
    /dev/serial/by-id: `tofcut_conveyor_factory`, the plugin's) and the project's client
    polling it. The belt's clock is `now[0]`: it moves only when the test moves it, so
    every count is known exactly."""

    def start(
        *,
        speed_mps: float = 0.25,
        start_count: int = 0,
        registers: RegisterMap | None = None,
        **link: float,
    ) -> tuple[EmulatedConveyor, ConveyorRig, ConveyorClient, list[float]]:
        now = [0.0]
        line = tofcut_conveyor_factory(
            speed_mps, clock=lambda: now[0], start_count=start_count, registers=registers,
            link=tmp_path / "ttyCONV0",
        )  # fmt: skip
        client = line.connect(registers, **{**FAST_SETTINGS, **link})
        return line.controller, line, client, now

    return start


def fresh(client: ConveyorClient, conveyor: EmulatedConveyor):
    """The first reading taken after this call that shows the controller's current count."""
    after = time.time_ns()
    count = conveyor.count()
    reading = client.wait_for(lambda r: r.time_ns > after and r.count == count, WAIT_S)
    assert reading is not None, client.stats
    return reading


@pytest.mark.parametrize(
    "registers",
    [
        None,
        RegisterMap(encoder=40, encoder_words="low-first", speed=5, status=20, diverter=1),
    ],
    ids=["default-map", "scattered-low-first"],
)
def test_encoder_speed_and_status_read_correctly_across_the_wrap(pty_line, registers):
    start = 2**32 - 1000  # the encoder register wraps 1000 counts into the run
    conveyor, _, client, now = pty_line(start_count=start, registers=registers)
    first = fresh(client, conveyor)
    assert first.count == start
    assert first.distance_m == 0.0
    assert first.speed_mps == pytest.approx(0.25)
    assert first.running
    assert not first.fault
    now[0] = 2.0  # 0.5 m at 0.25 m/s: 5000 counts at 10000 per metre
    later = fresh(client, conveyor)
    assert later.count == (start + 5000) % 2**32 == 4000
    assert later.distance_m == pytest.approx(0.5, abs=1e-12)
    conveyor.set_fault(True)
    assert client.wait_for(lambda r: r.fault, WAIT_S) is not None
    assert client.stats.failed_polls == 0


def test_the_velocity_prior_follows_a_speed_change(pty_line):
    conveyor, _, client, now = pty_line()
    slow = fresh(client, conveyor)
    prior = belt_velocity_prior(slow, DIRECTION)
    np.testing.assert_allclose(prior.mean, 0.25 * DIRECTION)
    conveyor.set_speed(0.6)
    fast = client.wait_for(lambda r: r.speed_mps == pytest.approx(0.6), WAIT_S)
    assert fast is not None
    prior = belt_velocity_prior(client.reading_at(fast.time_ns), DIRECTION)
    assert prior.informed
    np.testing.assert_allclose(prior.mean, 0.6 * DIRECTION)
    # Along the belt the prior is tight, across it looser.
    assert DIRECTION @ prior.cov @ DIRECTION < np.array([0.0, 1.0, 0.0]) @ prior.cov[:, 1]
    # The history still knows the slow part; the encoder agrees with the new speed.
    assert client.reading_at(slow.time_ns).speed_mps == pytest.approx(0.25)
    now[0] += 0.5
    assert fresh(client, conveyor).distance_m - fast.distance_m == pytest.approx(0.3)


def test_a_stopped_belt_is_stopped_not_lost(pty_line):
    conveyor, _, client, now = pty_line()
    fresh(client, conveyor)
    now[0] = 1.0
    conveyor.stop()
    stopped = client.wait_for(lambda r: not r.running, WAIT_S)
    assert stopped is not None
    assert stopped.speed_mps == 0.0
    readings = [stopped]
    for _ in range(3):  # time passes, readings keep coming, the belt stays put
        now[0] += 1.0
        last = readings[-1].time_ns
        readings.append(client.wait_for(lambda r, last=last: r.time_ns > last, WAIT_S))
    assert {r.distance_m for r in readings} == {0.25}
    stats = client.stats
    assert stats.link_up
    assert stats.failed_polls == 0
    assert stats.timeouts == 0
    prior = belt_velocity_prior(client.reading_at(time.time_ns()), DIRECTION)
    assert prior.informed
    np.testing.assert_array_equal(prior.mean, np.zeros(3))
    conveyor.start()
    now[0] += 1.0
    assert fresh(client, conveyor).distance_m == pytest.approx(0.5)


def test_the_heartbeat_counts_up(pty_line):
    conveyor, _, client, _now = pty_line(heartbeat_s=0.01)
    beats = conveyor.wait_heartbeats(3, WAIT_S)
    assert beats[:3] == [1, 2, 3]
    assert client.wait_stats(lambda s: s.heartbeats >= 3, WAIT_S).heartbeats >= 3


def test_crc_errors_and_exception_replies_are_retried_within_the_bound_and_counted(pty_line):
    conveyor, line, client, now = pty_line()
    fresh(client, conveyor)
    with line.spoiled("crc", 2):  # two bad replies: the third attempt gets through
        now[0] = 1.0
        assert fresh(client, conveyor).distance_m == pytest.approx(0.25)
    stats = client.stats
    assert stats.bad_frames >= 2
    assert stats.retries >= 2
    assert stats.failed_polls == 0
    with line.spoiled("exception", 3):  # one more than the retries: that poll fails
        stats = client.wait_stats(lambda s: s.exception_replies >= 3, WAIT_S)
    assert stats.exception_replies >= 3
    assert stats.failed_polls >= 1
    now[0] = 2.0
    assert fresh(client, conveyor).distance_m == pytest.approx(0.5)
    assert client.stats.link_up


def test_garbage_on_the_line_is_survived(pty_line):
    conveyor, line, client, now = pty_line()
    fresh(client, conveyor)
    with line.spoiled("garbage", 2):
        for _ in range(5):  # noise bursts between and into requests
            line.noise(40)
        stats = client.wait_stats(lambda s: s.bad_frames >= 2, WAIT_S)
    assert stats.bad_frames >= 2
    now[0] = 4.0
    assert fresh(client, conveyor).distance_m == pytest.approx(1.0)
    assert client.stats.link_up


def test_a_silent_controller_is_counted_and_never_blocks_the_caller(pty_line):
    conveyor, line, client, now = pty_line()
    before = fresh(client, conveyor)
    with line.silent():
        stats = client.wait_stats(lambda s: s.timeouts >= 3, WAIT_S)
        assert stats.timeouts >= 3
        assert not stats.link_up
        # While the link thread waits on the silent line, callers still get answers now.
        client.divert(99)
        assert client.latest().time_ns >= before.time_ns
        assert client.reading_at(time.time_ns() + 10**9) is None  # too long after: unknown
        stats = client.wait_stats(lambda s: s.diverter_late + s.diverter_failures >= 1, WAIT_S)
        assert stats.diverter_late + stats.diverter_failures == 1
        assert stats.diverter_writes == 0
    now[0] = 2.0
    assert fresh(client, conveyor).distance_m == pytest.approx(0.5)
    assert client.stats.link_up
    assert conveyor.diverter_commands == []  # a late push would hit the wrong object


def test_close_abandons_a_request_to_a_silent_controller_at_its_deadline(pty_line, caplog):
    conveyor, line, client, _now = pty_line(timeout_s=10.0, retries=10)
    fresh(client, conveyor)
    with line.silent():
        asked = line.server.stats.requests
        deadline = time.monotonic() + WAIT_S
        while line.server.stats.requests == asked:  # a request now waits for its 10 s timeout
            assert time.monotonic() < deadline
            time.sleep(0.001)
        closer = threading.Thread(target=client.close, kwargs={"deadline_s": 0.5})
        start = time.monotonic()
        closer.start()
        closer.join(WAIT_S)
        assert not closer.is_alive(), "close() waited on the silent controller"
        assert time.monotonic() - start < 0.5 + 2.0  # the deadline, and a busy machine's slack
        assert client._abandoned is not None
        assert client._abandoned.is_alive()
        assert client.stats.timeouts == 0  # the request was abandoned, not timed out
        with line.unplugged():  # the abandoned request ends with the port: no news after close
            client._abandoned.join(WAIT_S)
            assert not client._abandoned.is_alive()
    assert not [r for r in caplog.records if "lost" in r.getMessage()]


@pytest.mark.parametrize("heartbeat_s", [LINK_RANGES["heartbeat_s"][0], 1e-6])
def test_a_fast_heartbeat_does_not_starve_the_polls(tofcut_conveyor, heartbeat_s):
    """The fastest heartbeat a map may ask for, and (past the check) one always due."""
    link = tofcut_conveyor.link(**{**FAST_SETTINGS, "heartbeat_s": LINK_RANGES["heartbeat_s"][0]})
    object.__setattr__(link, "heartbeat_s", heartbeat_s)
    with ConveyorClient(link) as client:
        stats = client.wait_stats(lambda s: s.readings >= 20 and s.heartbeats >= 20, WAIT_S)
    assert stats.readings >= 20, stats
    assert stats.heartbeats >= 20, stats


def test_diverter_commands_queued_behind_a_stuck_link_are_bounded(pty_line):
    conveyor, line, client, _now = pty_line(timeout_s=10.0)
    fresh(client, conveyor)
    with line.silent():  # the link now waits up to 10 s for each reply
        for tag in range(COMMANDS_KEPT + 100):
            client.divert(tag)
        with client._lock:
            assert len(client._commands) <= COMMANDS_KEPT
        assert client.stats.diverter_late >= 99  # the oldest, dropped; one may be in flight
        client.close()  # the commands still queued go with it
    assert conveyor.diverter_commands == []


def test_the_port_vanishes_and_comes_back(pty_line):
    conveyor, line, client, now = pty_line()
    fresh(client, conveyor)
    with line.unplugged():  # the adapter is pulled out: the pty closes, the symlink goes
        assert not os.path.exists(line.port)
        stats = client.wait_stats(lambda s: s.disconnects >= 1, WAIT_S)
        assert stats.disconnects == 1
        assert not stats.link_up
    # plugged back in: a new pty behind the same path
    assert client.wait_stats(lambda s: s.reopens >= 1, WAIT_S).reopens == 1
    now[0] = 3.0
    assert fresh(client, conveyor).distance_m == pytest.approx(0.75)
    assert client.stats.link_up


def test_opening_a_missing_port_says_which(tmp_path):
    missing = str(tmp_path / "ttyNONE")
    with pytest.raises(LinkError, match="ttyNONE"):
        ConveyorClient(replace(FAST_LINK, port=missing)).open()


def test_crc16_is_the_standard_modbus_crc():
    rng = random.Random(5)
    for n in (1, 2, 7, 64, 255):
        data = rng.randbytes(n)
        assert crc16(data) == int.from_bytes(FramerRTU.compute_CRC(data).to_bytes(2), "little")
    # The specification's example: read 10 registers from 0 of unit 1 ends in C5 CD.
    assert crc16(bytes.fromhex("01030000000A")).to_bytes(2, "little").hex() == "c5cd"


def test_pymodbus_own_client_against_the_emulated_controller(tofcut_conveyor_factory):
    now = [0.0]
    line = tofcut_conveyor_factory(0.25, clock=lambda: now[0], start_count=0x12345)
    conveyor = line.controller
    now[0] = 2.0
    client = ModbusSerialClient(
        line.port, framer=FramerType.RTU, baudrate=19200, parity="N",
        timeout=0.2, retries=0,
    )  # fmt: skip
    assert client.connect()
    try:
        count = 0x12345 + 5000
        reply = client.read_holding_registers(0, count=4, device_id=1)
        assert not reply.isError()
        assert list(reply.registers) == [count >> 16, count & 0xFFFF, 250, 0b01]
        assert not client.write_register(10, 7, device_id=1).isError()
        (command,) = conveyor.diverter_commands
        assert (command.value, command.count) == (7, count)
        assert not client.write_registers(11, [42], device_id=1).isError()
        assert conveyor.heartbeats == [42]
        assert client.read_holding_registers(60, count=10, device_id=1).exception_code == 2
        assert client.write_register(0, 1, device_id=1).exception_code == 2  # read-only
        assert client.read_input_registers(0, count=1, device_id=1).exception_code == 1
        with pytest.raises(ModbusIOException):  # another unit on the bus: no answer
            client.read_holding_registers(0, count=1, device_id=2)
        with line.spoiled("crc"), pytest.raises(ModbusIOException):  # pymodbus rejects it too
            client.read_holding_registers(0, count=1, device_id=1)
        with line.spoiled("exception"):
            assert client.read_holding_registers(0, count=1, device_id=1).exception_code == 6
        assert line.server.stats.other_units == 1
    finally:
        client.close()


@contextmanager
def pymodbus_tcp_server(registers: list[int], writes: list[tuple[int, list[int]]]):
    """pymodbus's own server on loopback, unit 1, holding registers from address 0."""

    async def record(fc, start, address, count, current, values):
        if values is not None:
            writes.append((address, list(values)))

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    device = SimDevice(
        1, simdata=[SimData(0, values=registers, datatype=DataType.REGISTERS)], action=record
    )

    async def start() -> ModbusTcpServer:
        server = ModbusTcpServer(device, address=("127.0.0.1", port))
        await server.serve_forever(background=True)  # listening when it returns
        return server

    loop = asyncio.new_event_loop()
    server = loop.run_until_complete(start())
    thread = threading.Thread(target=loop.run_forever, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{port}"
    finally:
        asyncio.run_coroutine_threadsafe(server.shutdown(), loop).result(WAIT_S)
        loop.call_soon_threadsafe(loop.stop)
        thread.join()
        loop.close()


def test_the_project_client_against_pymodbus_own_server_over_tcp():
    """The same client code reaches a Modbus TCP gateway; the server is pymodbus's."""
    writes: list[tuple[int, list[int]]] = []
    count = 0x0001_2345
    registers = [count >> 16, count & 0xFFFF, (-120) & 0xFFFF, 0b11] + [0] * 12
    with pymodbus_tcp_server(registers, writes) as url:
        link = replace(FAST_LINK, port=url, heartbeat_s=0.01)
        with ConveyorClient(link) as client:
            reading = client.wait_for(lambda r: True, WAIT_S)
            assert reading.count == count
            assert reading.speed_mps == pytest.approx(-0.12)  # signed: running backwards
            assert reading.running
            assert reading.fault
            client.divert(5)
            stats = client.wait_stats(lambda s: s.diverter_writes and s.heartbeats >= 2, WAIT_S)
            assert stats.diverter_writes == 1
            assert stats.failed_polls == 0
    assert (10, [1]) in writes
    assert [v for a, v in writes if a == 11][:2] == [[1], [2]]
