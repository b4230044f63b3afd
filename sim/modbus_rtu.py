"""Modbus RTU framing for the emulated controller: CRC-16, request lengths, replies.

An RTU frame is unit id, function code, data and a CRC-16 (polynomial 0xA001 reflected,
initial 0xFFFF, low byte first). Only what a conveyor controller serves is here: read
holding registers (3), write one register (6), write several (16); anything else gets the
"illegal function" exception.
"""

from __future__ import annotations

import enum
import struct
from typing import Protocol

READ_HOLDING = 3
WRITE_ONE = 6
WRITE_MANY = 16
MAX_READ = 125
MAX_WRITE = 123


class ExceptionCode(enum.IntEnum):
    """Modbus exception codes (the byte after a function code with its top bit set)."""

    ILLEGAL_FUNCTION = 1
    ILLEGAL_ADDRESS = 2
    ILLEGAL_VALUE = 3
    DEVICE_FAILURE = 4
    BUSY = 6


class ModbusFault(Exception):
    """A request the device refuses; the server answers with this exception code."""

    def __init__(self, code: ExceptionCode, message: str = "") -> None:
        super().__init__(message or code.name)
        self.code = code


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Modbus CRC-16 of `data`, as an integer (sent low byte first)."""
    crc = 0xFFFF
    for b in data:
        crc = (crc >> 8) ^ _TABLE[(crc ^ b) & 0xFF]
    return crc


def frame(body: bytes) -> bytes:
    """Unit id + PDU → the RTU frame with its CRC."""
    return body + struct.pack("<H", crc16(body))


def crc_ok(frame_bytes: bytes) -> bool:
    return (
        len(frame_bytes) >= 4
        and crc16(frame_bytes[:-2]) == struct.unpack("<H", frame_bytes[-2:])[0]
    )


def request_length(buf: bytes | bytearray) -> int | None:
    """The length of the request at the start of `buf`, or None while it cannot be known
    (too few bytes yet, or a function code whose length only the line's silence tells)."""
    if len(buf) < 2:
        return None
    fc = buf[1]
    if 1 <= fc <= 6:
        return 8
    if fc in (15, 16):
        return 9 + buf[6] if len(buf) >= 7 else None
    return None


def exception_reply(unit: int, function: int, code: int) -> bytes:
    return frame(bytes([unit, function | 0x80, code]))


class RegisterDevice(Protocol):
    """What a Modbus server serves: holding registers, refusing with `ModbusFault`."""

    def read(self, address: int, count: int) -> list[int]: ...

    def write(self, address: int, values: list[int]) -> None: ...


def serve(unit: int, request: bytes, device: RegisterDevice) -> bytes:
    """The reply frame to a CRC-checked request frame addressed to this unit."""
    fc = request[1]
    try:
        if fc == READ_HOLDING:
            address, count = struct.unpack(">HH", request[2:6])
            if not 1 <= count <= MAX_READ:
                raise ModbusFault(ExceptionCode.ILLEGAL_VALUE)
            values = device.read(address, count)
            return frame(bytes([unit, fc, 2 * count]) + struct.pack(f">{count}H", *values))
        if fc == WRITE_ONE:
            address, value = struct.unpack(">HH", request[2:6])
            device.write(address, [value])
            return frame(request[:6])
        if fc == WRITE_MANY:
            address, count, nbytes = struct.unpack(">HHB", request[2:7])
            if not 1 <= count <= MAX_WRITE or nbytes != 2 * count:
                raise ModbusFault(ExceptionCode.ILLEGAL_VALUE)
            device.write(address, list(struct.unpack(f">{count}H", request[7 : 7 + nbytes])))
            return frame(request[:6])
        raise ModbusFault(ExceptionCode.ILLEGAL_FUNCTION)
    except ModbusFault as exc:
        return exception_reply(unit, fc, exc.code)
