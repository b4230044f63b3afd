"""Fuzzing, one test per input format: capture files, calibration blocks, scene files,
conveyor maps, reject rules and Modbus replies. Fixed seeds and a few hundred mutated cases
each; every case must end in one of the package's documented errors (a `TofcutError`: the
format's own `CaptureError`, `ProtocolError`, `SceneError`, `ConfigError`) or in a usable
result, never in another exception or a crash.

The capture and scene fuzzers run in a subprocess, so that a segfault (a compiled kernel
writing out of bounds) fails the test instead of ending the suite, and so that their peak
memory (`MAX_RSS_MB`) is measured alone.
"""

from __future__ import annotations

import math
import random
import re
import resource
import struct
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tofcut.driver.calibration import Calibration, pack_calibration, parse_calibration
from tofcut.driver.conveyor.config import LinkSettings, load_conveyor_config
from tofcut.driver.conveyor.link import ConveyorClient
from tofcut.driver.conveyor.reject_rule import PROPERTIES, RejectRule, TrackMeasures
from tofcut.driver.demod import Optics
from tofcut.driver.errors import TofcutError
from tofcut.driver.protocol import crc32
from tofcut.sim.conveyor import EmulatedConveyor
from tofcut.sim.modbus_rtu import crc16, serve
from tofcut.sim.modbus_server import PtyModbusServer
from tofcut.sim.pattern import pattern_calibration
from tofcut.tracker.tracks import Track

HERE = Path(__file__).resolve().parent
SCENES = HERE.parent / "sim" / "scenes"
CASES = 300
MAX_RSS_MB = 1024
"""Peak resident memory a fuzzing subprocess may reach (Python, numpy and the package take
about 120 MB; the inputs are small, so anything near this bound is a size read unchecked)."""

MAX_MESSAGE = 600
"""An error is one line of at most this many characters (what it quotes is cut short)."""
INTERESTING_INTS = [0, 1, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 2**31 - 1, 2**31, 2**32 - 1]
INTERESTING_TOML = [
    "nan", "inf", "-inf", "-1", "0", "-0.0", "1e300", "-1e300", "1e-300", '"x"', '"false"',
    "true", "false", "[]", "{}", "[nan, nan, nan]", "[0, 0, 0]", "[1e300, 0, 0]",
    "99999999999999999999999", "4096", "100000", "0.000001", "[1, 2]", '""', '"' + "x" * 5000 + '"',
]  # fmt: skip


class Failure(AssertionError):
    pass


# --- mutators ---------------------------------------------------------------------------------


def mutate_bytes(data: bytes, rng: random.Random, edits: int | None = None) -> bytes:
    """A few random edits: bit flips, interesting integers, cuts, inserts, duplicated spans."""
    out = bytearray(data)
    for _ in range(edits or rng.randint(1, 4)):
        n = len(out)
        kind = rng.randrange(7)
        pos = rng.randrange(n) if n else 0
        if kind == 0 and n:
            out[pos] ^= 1 << rng.randrange(8)
        elif kind == 1 and n:
            out[pos] = rng.choice([0, 0xFF, 0x7F, 0x80, rng.randrange(256)])
        elif kind == 2 and n >= 4:
            pos = rng.randrange(n - 3)
            out[pos : pos + 4] = struct.pack("<I", rng.choice(INTERESTING_INTS))
        elif kind == 3:
            del out[pos : pos + rng.randint(1, 64)]
        elif kind == 4:
            out[pos:pos] = rng.randbytes(rng.randint(1, 32))
        elif kind == 5 and n:
            span = out[pos : pos + rng.randint(1, 256)]
            at = rng.randrange(n)
            out[at:at] = span
        else:
            del out[rng.randrange(n + 1) :]
    return bytes(out)


_VALUE = re.compile(r"(?<==)\s*([^\n#]+)")


def mutate_toml(text: str, rng: random.Random) -> bytes:
    """TOML-aware edits (values replaced by odd ones, keys and tables misspelt, lines dropped,
    doubled or swapped), now and then raw byte edits on top."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        if not lines:
            break
        i = rng.randrange(len(lines))
        kind = rng.randrange(6)
        if kind in (0, 1) and "=" in lines[i]:
            key = lines[i].split("=", 1)[0]
            lines[i] = f"{key}= {rng.choice(INTERESTING_TOML)}"
        elif kind == 2 and lines[i].strip():
            word = lines[i]
            j = rng.randrange(len(word))
            lines[i] = word[:j] + rng.choice(["s", "", "_", word[j] * 2]) + word[j + 1 :]
        elif kind == 3:
            del lines[i]
        elif kind == 4:
            lines.insert(rng.randrange(len(lines) + 1), lines[i])
        else:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
    data = ("\n".join(lines) + "\n").encode()
    if rng.random() < 0.15:
        data = mutate_bytes(data, rng, 1)
    return data


def run_cases(
    name: str, seed: int, cases: int, make: Callable[[random.Random], object],
    check: Callable[[object], None], failures: list[str],
) -> None:  # fmt: skip
    """`check(make(rng))` for every case: a `TofcutError` is a refused input (fine); any other
    exception is a failure, listed with the case's number and a traceback."""
    for i in range(cases):
        rng = random.Random(f"{name}-{seed}-{i}")
        case = make(rng)
        try:
            check(case)
        except TofcutError as exc:
            if "\n" in str(exc) or len(str(exc)) > MAX_MESSAGE:
                failures.append(f"{name} case {i}: not one short line: {str(exc)[:2000]!r}")
        except Exception:
            failures.append(f"{name} case {i}:\n{traceback.format_exc(limit=6)}")


# --- capture files (in a subprocess) ----------------------------------------------------------


def fuzz_captures(tmp: Path, seed: int, cases: int) -> list[str]:
    from test_driver_properties import write_capture

    from tofcut.driver.capture import CaptureReader

    good = tmp / "good.tofcap"
    write_capture(good, 5)
    data = good.read_bytes()
    path = tmp / "case.tofcap"

    def check(case: object) -> None:
        assert isinstance(case, bytes)
        path.write_bytes(case)
        reader = CaptureReader(path)
        with np.errstate(all="ignore"):
            for frame in reader.frames():
                assert frame.xyz.shape == (reader.info.height, reader.info.width, 3)

    failures: list[str] = []
    run_cases("capture", seed, cases, lambda rng: mutate_bytes(data, rng), check, failures)
    return failures


# --- scene files (in a subprocess) ------------------------------------------------------------


SCENE_RENDERS = 12
"""Of the mutated scene files that load, the first this many are rendered (one frame each)."""


def fuzz_scenes(tmp: Path, seed: int, cases: int) -> list[str]:
    from tofcut.sim.preview import scene_exposure
    from tofcut.sim.renderer import SceneSource
    from tofcut.sim.scene_file import load_scene

    texts = [p.read_text() for p in sorted(SCENES.glob("*.toml"))]
    path = tmp / "case.toml"
    rendered = [0]

    def check(case: object) -> None:
        assert isinstance(case, bytes)
        path.write_bytes(case)
        scene = load_scene(path)
        if rendered[0] < SCENE_RENDERS and scene.lens.width * scene.lens.height <= 176 * 144:
            rendered[0] += 1
            src = SceneSource(scene, 0)
            with np.errstate(all="ignore"):
                out = src.render(scene_exposure(src, 0.37 * scene.duration_s, 0))
            assert out.taps.shape == (4, scene.lens.height, scene.lens.width)

    failures: list[str] = []
    run_cases(
        "scene", seed, cases, lambda rng: mutate_toml(rng.choice(texts), rng), check, failures
    )
    return failures


SUBPROCESS = """
import re, sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
import test_fuzz
failures = getattr(test_fuzz, sys.argv[2])(Path(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]))
for f in failures[:5]:
    print(f, file=sys.stderr)
# this program's own peak (VmHWM): Linux carries ru_maxrss over from the parent across exec,
# so it would report the test runner's peak instead
peak_kb = int(re.search(r"VmHWM:\\s+(\\d+)", Path("/proc/self/status").read_text()).group(1))
print(len(failures), peak_kb // 1024)
"""


@pytest.mark.parametrize("fuzzer", ["fuzz_captures", "fuzz_scenes"])
def test_fuzzed_files_in_a_subprocess(tmp_path, fuzzer):
    result = subprocess.run(
        [sys.executable, "-c", SUBPROCESS, str(HERE), fuzzer, str(tmp_path), "1", str(CASES)],
        capture_output=True, text=True, timeout=240, check=False,
    )  # fmt: skip
    assert result.returncode == 0, f"the fuzzer died ({result.returncode}):\n{result.stderr}"
    failures, rss_mb = (int(x) for x in result.stdout.split()[-2:])
    assert failures == 0, result.stderr
    assert rss_mb < MAX_RSS_MB


# --- calibration blocks -----------------------------------------------------------------------


def _recrc(block: bytes) -> bytes:
    """The block with its CRC made right again, so that the fields behind it are checked."""
    if len(block) < 64:
        return block
    return block[:60] + struct.pack("<I", crc32(block[:60] + block[64:])) + block[64:]


def test_fuzzed_calibration_blocks():
    blocks = [pack_calibration(pattern_calibration(w, h, seed=3)) for w, h in ((8, 6), (17, 5))]

    def make(rng: random.Random) -> bytes:
        block = mutate_bytes(rng.choice(blocks), rng)
        return _recrc(block) if rng.random() < 0.7 else block

    def check(case: object) -> None:
        assert isinstance(case, bytes)
        calib = parse_calibration(case)
        assert isinstance(calib, Calibration)
        with np.errstate(all="ignore"):
            optics = Optics.from_calibration(calib)
        assert np.isfinite(optics.rays).all()

    failures: list[str] = []
    start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    run_cases("calibration", 1, CASES, make, check, failures)
    assert not failures, "\n".join(failures[:5])
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - start) / 1024
    assert grown_mb < 100


# --- conveyor maps ----------------------------------------------------------------------------


def _map_example() -> str:
    import tofcut.driver.conveyor.config as module

    doc = module.__doc__ or ""
    lines = doc.split("::", 1)[1].splitlines()
    return "\n".join(line[4:] for line in lines if line.startswith("    "))


def test_fuzzed_conveyor_maps(tmp_path):
    text = _map_example()
    assert load_conveyor_config  # the example itself loads:
    good = tmp_path / "good.toml"
    good.write_text(text)
    assert load_conveyor_config(good).registers.counts_per_m == 10000.0
    path = tmp_path / "case.toml"

    def check(case: object) -> None:
        assert isinstance(case, bytes)
        path.write_bytes(case)
        config = load_conveyor_config(path)
        assert 0.001 <= config.link.timeout_s <= 10
        assert 0.1 <= config.link.poll_hz <= 1000

    failures: list[str] = []
    run_cases("map", 1, CASES, lambda rng: mutate_toml(text, rng), check, failures)
    assert not failures, "\n".join(failures[:5])


# --- reject rules -----------------------------------------------------------------------------

RULE_WORDS = [
    *PROPERTIES, "and", "or", "not", "(", ")", "<", "<=", ">", ">=", "==", "!=", "0.08", "1e999",
    "-1e-320", "nan", "inf", "0", "-0", ".5", "5.", "1e", "+", "-", "heigth", "__import__",
    "'x'", "lambda", ",", ";", "é", "\x00", "\n",
]  # fmt: skip


def _measures(rng: random.Random) -> TrackMeasures:
    values = [rng.choice([0.0, 1.0, -1.0, 1e308, rng.uniform(-1, 1)]) for _ in range(6)]
    track = Track(1, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), (0, 0, 1, 1), 5,
                  np.zeros((0, 3), np.float32))  # fmt: skip
    return TrackMeasures(1, *values[:5], pixels=rng.randint(0, 10**6), along=0.0, track=track)


def test_fuzzed_reject_rules():
    good = ["height > 0.08", "0.05 < length <= 0.3 and not (width < 0.1 or pixels < 10)"]

    def make(rng: random.Random) -> tuple[str, TrackMeasures]:
        if rng.random() < 0.5:
            words = rng.choices(RULE_WORDS, k=rng.randint(0, 25))
            text = " ".join(words)
        else:
            text = mutate_bytes(rng.choice(good).encode(), rng).decode("utf-8", "replace")
        if rng.random() < 0.05:
            text = rng.choice(["(", "not "]) * rng.randint(50, 20_000) + text
        return text, _measures(rng)

    def check(case: object) -> None:
        text, measures = case  # type: ignore[misc]
        rule = RejectRule.parse(text)
        assert rule(measures) in (True, False)

    failures: list[str] = []
    run_cases("rule", 1, CASES, make, check, failures)
    assert not failures, "\n".join(failures[:5])


# --- Modbus replies ---------------------------------------------------------------------------


class FuzzedReplies(PtyModbusServer):
    """The emulated controller, each reply mutated: its bytes edited, cut, grown or replaced,
    and for most a CRC made right again, so that well-formed frames with wrong contents
    (another function, byte count, unit, exception code) reach the client's parser."""

    def __init__(self, *args: object, seed: int = 1, **kwargs: object) -> None:
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]
        self._fuzz = random.Random(seed)
        self.fuzzed = 0

    def _answer(self, request: bytes) -> None:
        self.stats.requests += 1
        rng = self._fuzz
        reply = serve(self.unit, request, self.device)
        if rng.random() < 0.8:
            body = mutate_bytes(reply[:-2], rng, rng.randint(1, 2))
            reply = body + struct.pack("<H", crc16(body)) if rng.random() < 0.7 else body
            self.fuzzed += 1
        if reply:
            import os

            os.write(self._master, reply)


def test_fuzzed_modbus_replies(tmp_path):
    conveyor = EmulatedConveyor(0.25)
    link = LinkSettings(parity="N", timeout_s=0.01, retries=1, poll_hz=1000.0, heartbeat_s=0.05,
                        reopen_s=0.01)  # fmt: skip
    readings = []
    errors: list[BaseException] = []
    hook = threading.excepthook
    threading.excepthook = lambda args: errors.append(args.exc_value)  # type: ignore[assignment]
    try:
        with FuzzedReplies(conveyor, link=tmp_path / "ttyFUZZ") as server:
            client = ConveyorClient(replace(link, port=server.port))
            client.add_listener(readings.append)
            with client:
                for i in range(40):
                    client.divert(i)
                stats = client.wait_stats(lambda s: server.fuzzed >= CASES, 20.0)
                assert client._thread is not None
                assert client._thread.is_alive()
    finally:
        threading.excepthook = hook
    assert not errors
    assert server.fuzzed >= CASES, stats
    assert stats.bad_frames + stats.timeouts + stats.exception_replies > 0
    for r in readings:
        assert 0 <= r.count < 2**32
        assert math.isfinite(r.distance_m)
        assert math.isfinite(r.speed_mps)


if __name__ == "__main__":  # pragma: no cover - run one fuzzer by hand: python test_fuzz.py NAME
    start = time.perf_counter()
    found = globals()[sys.argv[1]](Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]))
    print("\n".join(found[:10]), len(found), f"{time.perf_counter() - start:.1f} s")
