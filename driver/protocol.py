"""SR-USB wire protocol, version 1: constants and byte layouts (spec §1–§6).

Pure functions only: packing and parsing of the GET_INFO reply and the frame header.
The driver and the emulated camera both use them, so the two cannot drift apart.
"""

from __future__ import annotations

import enum
import struct
import zlib
from dataclasses import dataclass

from tofcut.driver.errors import ProtocolError

VENDOR_ID = 0x0852
PRODUCT_ID = 0x0074
MANUFACTURER = "SR-compatible"
PRODUCT = "SR4K-USB TOF camera"
INTERFACE = 0
ENDPOINT_FRAMES = 0x86
MAX_PACKET = 512

REQ_TYPE_IN = 0xC0
REQ_TYPE_OUT = 0x40

SPEED_OF_LIGHT = 299_792_458.0
TAPS = 4
MAX_COUNT = 16383
"""Raw counts are 14-bit; this value means saturated."""


class Request(enum.IntEnum):
    """Vendor control requests (spec §2)."""

    GET_INFO = 0x10
    READ_REG = 0x11
    WRITE_REG = 0x12
    STREAM = 0x13
    TRIGGER = 0x14
    READ_FLASH = 0x15


FLASH_BLOCK = 64
"""READ_FLASH returns the calibration block in pieces of this size."""


class Register(enum.IntEnum):
    """Camera registers, all u16 (spec §4)."""

    MOD_FREQ = 0x00
    INTEGRATION = 0x01
    FRAME_PERIOD = 0x02
    TRIGGER_MODE = 0x03
    STATUS = 0x04
    TEMPERATURE = 0x05


WRITABLE_REGISTERS = frozenset(
    {Register.MOD_FREQ, Register.INTEGRATION, Register.FRAME_PERIOD, Register.TRIGGER_MODE}
)
RESET_VALUES = {
    Register.MOD_FREQ: 1,
    Register.INTEGRATION: 30,
    Register.FRAME_PERIOD: 200,
    Register.TRIGGER_MODE: 0,
}

STATUS_STREAMING = 1 << 0
STATUS_OVER_TEMPERATURE = 1 << 1
STATUS_FIFO_OVERFLOW = 1 << 2

MOD_FREQ_MHZ: dict[int, float] = {
    1: 30.0,
    5: 60.0,
    6: 15.0,
    7: 10.0,
    8: 29.0,
    9: 31.0,
    10: 14.5,
    11: 15.5,
}
"""Modulation frequency code → MHz; codes 0, 2, 3 and 4 are not supported."""

MAX_INTEGRATION = 255
MAX_FPS = 54


def mod_freq_hz(code: int) -> float:
    """Modulation frequency in Hz for a MOD_FREQ code."""
    try:
        return MOD_FREQ_MHZ[code] * 1e6
    except KeyError:
        raise ProtocolError(f"unsupported modulation frequency code {code}") from None


def unambiguous_range_m(code: int) -> float:
    """Distances are known modulo this many metres (c / 2f)."""
    return SPEED_OF_LIGHT / (2.0 * mod_freq_hz(code))


def integration_us(value: int) -> int:
    """Exposure time of one tap in µs for an INTEGRATION register value."""
    return 300 + 100 * value


def crc32(data: bytes | bytearray | memoryview) -> int:
    """The protocol's checksum: zlib's CRC-32."""
    return zlib.crc32(data) & 0xFFFFFFFF


# --- GET_INFO (spec §3) -----------------------------------------------------------------------

INFO_MAGIC = b"SRI1"
INFO_SIZE = 32
_INFO = struct.Struct("<4sHHIHHIH6x")


@dataclass(frozen=True)
class DeviceInfo:
    """What GET_INFO says about the camera."""

    protocol: int
    firmware: int
    serial: int
    width: int
    height: int
    calibration_size: int
    max_fps: int

    @property
    def serial_text(self) -> str:
        """Serial number as the string descriptor shows it: 8 upper-case hex digits."""
        return f"{self.serial:08X}"

    @property
    def frame_size(self) -> int:
        """Bytes of one frame on the wire: header and payload."""
        return HEADER_SIZE + self.payload_size

    @property
    def payload_size(self) -> int:
        return TAPS * self.width * self.height * 2

    def described(self) -> dict[str, int | str]:
        """The camera as a capture's metadata and `tofcut info --json` name it."""
        return {
            "serial": self.serial_text,
            "firmware": self.firmware,
            "protocol": self.protocol,
            "width": self.width,
            "height": self.height,
            "max_fps": self.max_fps,
        }


MAX_SENSOR_SIDE = 4096
"""No sensor of this family is wider or taller; a bigger size read from the wire is damage."""
MAX_SENSOR_PIXELS = (FLASH_BLOCK * 0x10000 - 64) // 2
"""The most pixels (W × H) a camera of this protocol can have: 2,097,120, e.g. 1448 × 1448
(the SR4K has 176 × 144 = 25,344). READ_FLASH numbers its 64-byte blocks with the request's
16-bit wValue (spec §2), so the calibration block — a 64-byte header and 2 bytes a pixel
(§5) — is at most 4 MiB. Everything sized by the sensor (frames, rays, images) is
proportional to this: a bigger size from the wire, a file or a scene is refused."""


def check_sensor_size(width: int, height: int) -> str:
    """'' for a sensor size a camera of this protocol can have, else why not (one line)."""
    if not (0 < width <= MAX_SENSOR_SIDE and 0 < height <= MAX_SENSOR_SIDE):
        return f"an impossible sensor size {width}x{height} (each side 1..{MAX_SENSOR_SIDE})"
    if width * height > MAX_SENSOR_PIXELS:
        return (
            f"an impossible sensor size {width}x{height}: more than {MAX_SENSOR_PIXELS} pixels, "
            "the most a calibration block readable with READ_FLASH can describe"
        )
    return ""


def pack_info(info: DeviceInfo) -> bytes:
    body = _INFO.pack(
        INFO_MAGIC,
        info.protocol,
        info.firmware,
        info.serial,
        info.width,
        info.height,
        info.calibration_size,
        info.max_fps,
    )
    return body + struct.pack("<I", crc32(body))


def parse_info(data: bytes | bytearray | memoryview) -> DeviceInfo:
    """Parse and check a GET_INFO reply; raises ProtocolError on anything off."""
    data = bytes(data)
    if len(data) != INFO_SIZE:
        raise ProtocolError(f"GET_INFO reply is {len(data)} bytes, expected {INFO_SIZE}")
    magic, protocol, firmware, serial, width, height, calib_size, max_fps = _INFO.unpack(data[:28])
    if magic != INFO_MAGIC:
        raise ProtocolError(f"GET_INFO magic is {magic!r}, expected {INFO_MAGIC!r}")
    (crc,) = struct.unpack("<I", data[28:])
    if crc != crc32(data[:28]):
        raise ProtocolError("GET_INFO reply fails its CRC")
    if protocol != 1:
        raise ProtocolError(f"protocol version {protocol} is not supported (this driver speaks 1)")
    if why := check_sensor_size(width, height):
        raise ProtocolError(f"GET_INFO reports {why}")
    expected_calib = CALIB_HEADER_SIZE + 2 * width * height
    if calib_size != expected_calib:
        raise ProtocolError(
            f"GET_INFO reports a calibration block of {calib_size} bytes, "
            f"expected {expected_calib} for {width}x{height}"
        )
    return DeviceInfo(protocol, firmware, serial, width, height, calib_size, max_fps)


# --- Frame header (spec §6) -------------------------------------------------------------------

FRAME_MAGIC = b"SRFM"
HEADER_SIZE = 64
_HEADER = struct.Struct("<4sHHIQHHBBBBhHII20x")

FLAG_SATURATED = 1 << 0
FLAG_OVER_TEMPERATURE = 1 << 1
FLAG_DROPPED_BEFORE = 1 << 2


@dataclass(frozen=True)
class FrameHeader:
    """One frame's header, as sent before its taps."""

    sequence: int
    device_time_us: int
    width: int
    height: int
    mod_code: int
    integration: int
    flags: int
    temperature_c: float
    tap_interval_us: int
    payload_size: int
    payload_crc: int
    taps: int = TAPS

    @property
    def dropped_before(self) -> bool:
        """The device dropped frames right before this one."""
        return bool(self.flags & FLAG_DROPPED_BEFORE)

    @property
    def saturated(self) -> bool:
        return bool(self.flags & FLAG_SATURATED)


def pack_header(header: FrameHeader) -> bytes:
    body = _HEADER.pack(
        FRAME_MAGIC,
        1,
        HEADER_SIZE,
        header.sequence & 0xFFFFFFFF,
        header.device_time_us,
        header.width,
        header.height,
        header.taps,
        header.mod_code,
        header.integration,
        header.flags,
        round(header.temperature_c * 100),
        header.tap_interval_us,
        header.payload_size,
        header.payload_crc,
    )
    return body + struct.pack("<I", crc32(body))


def parse_header(data: bytes | bytearray | memoryview) -> FrameHeader:
    """Parse a 64-byte frame header, checking magic, versions and the header CRC.

    Sizes are not checked against a device here; see `check_header`.
    """
    if len(data) < HEADER_SIZE:
        raise ProtocolError(f"frame header needs {HEADER_SIZE} bytes, got {len(data)}")
    view = memoryview(data)[:HEADER_SIZE]
    (
        magic,
        version,
        header_size,
        sequence,
        device_time_us,
        width,
        height,
        taps,
        mod_code,
        integration,
        flags,
        temperature,
        tap_interval_us,
        payload_size,
        payload_crc,
    ) = _HEADER.unpack(view[:60])
    if magic != FRAME_MAGIC:
        raise ProtocolError(f"frame magic is {bytes(magic)!r}, expected {FRAME_MAGIC!r}")
    (crc,) = struct.unpack("<I", view[60:64])
    if crc != crc32(view[:60]):
        raise ProtocolError("frame header fails its CRC")
    if version != 1 or header_size != HEADER_SIZE:
        raise ProtocolError(f"frame header version {version} / size {header_size} not supported")
    return FrameHeader(
        sequence=sequence,
        device_time_us=device_time_us,
        width=width,
        height=height,
        mod_code=mod_code,
        integration=integration,
        flags=flags,
        temperature_c=temperature / 100.0,
        tap_interval_us=tap_interval_us,
        payload_size=payload_size,
        payload_crc=payload_crc,
        taps=taps,
    )


def check_header(header: FrameHeader, info: DeviceInfo) -> None:
    """Refuse a header whose sizes disagree with what the device said in GET_INFO."""
    if (header.width, header.height) != (info.width, info.height):
        raise ProtocolError(
            f"frame is {header.width}x{header.height}, the sensor is {info.width}x{info.height}"
        )
    if header.taps != TAPS:
        raise ProtocolError(f"frame has {header.taps} taps, expected {TAPS}")
    if header.payload_size != info.payload_size:
        raise ProtocolError(
            f"frame payload is {header.payload_size} bytes, expected {info.payload_size}"
        )


# --- Calibration block header (spec §5) -------------------------------------------------------

CALIB_MAGIC = b"SRCB"
CALIB_HEADER_SIZE = 64
