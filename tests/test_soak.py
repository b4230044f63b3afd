"""`tofcut soak`: where each lost frame is booked, the fault schedule, the memory measure,
and a few seconds of the real thing on the emulator's virtual clock."""

from __future__ import annotations

import random
import re
from types import SimpleNamespace

import pytest

from tofcut.driver.stream import StreamStats
from tofcut.sim.drill import FAULTS
from tofcut.tools.cli import main
from tofcut.tools.experiments.soak import (
    HOST_OVERFLOW,
    UNEXPLAINED,
    FaultInjector,
    LossAudit,
    growth,
)


def frame(flagged: bool = False) -> SimpleNamespace:
    """What the audit reads of a received frame: the camera's 'dropped before' flag."""
    return SimpleNamespace(header=SimpleNamespace(dropped_before=flagged))


def test_losses_go_to_the_open_fault_else_to_the_cameras_flag_else_unexplained():
    stats = StreamStats()
    audit = LossAudit(stats, settle_frames=3)
    audit.see(frame())
    stats.record_gap(5, 6)  # the camera flagged it: its FIFO overflowed
    audit.see(frame(flagged=True))
    stats.record_gap(9, 9)  # nobody knows why
    audit.see(frame())
    audit.begin("unplugged")
    assert audit.open_window == "unplugged"
    stats.record_gap(20, 29, estimated=True)
    stats.reconnects += 1
    audit.see(frame(flagged=True))  # within the window the fault is the cause, flag or not
    stats.damaged += 1
    stats.record_gap(30, 30)
    audit.see(frame())
    audit.see(frame())  # the third frame since the fault: the window closes
    assert audit.open_window is None
    assert audit.wait_settled(0)
    stats.record_gap(40, 41)
    audit.see(frame())
    t = audit.tallies
    assert (t[HOST_OVERFLOW].lost, list(t[HOST_OVERFLOW].ranges)) == (2, [(5, 6)])
    assert (t[UNEXPLAINED].lost, list(t[UNEXPLAINED].ranges)) == (3, [(9, 9), (40, 41)])
    fault = t["unplugged"]
    assert (fault.injected, fault.lost, fault.estimated, fault.damaged, fault.reconnects) == (
        1, 11, 10, 1, 1,
    )  # fmt: skip
    assert fault.describe_ranges() == "20-29 (estimated), 30"
    assert audit.accounted == stats.lost == 16


def test_a_flagged_outage_is_not_taken_for_an_overflow_and_leftovers_are_booked():
    stats = StreamStats()
    audit = LossAudit(stats)
    stats.record_gap(3, 8, estimated=True)  # an outage nobody injected, whatever the flag says
    audit.see(frame(flagged=True))
    stats.record_gap(12, 12)  # counted as the reader stopped, never handed on
    audit.finish()
    assert audit.tallies[UNEXPLAINED].lost == 7
    assert audit.accounted == stats.lost
    audit.begin("hung firmware")
    with pytest.raises(RuntimeError, match="has not settled"):
        audit.begin("unplugged")


def test_every_kind_of_fault_comes_once_a_round_in_a_seeded_order():
    def order(seed: int) -> list[str]:
        injector = FaultInjector(dict.fromkeys(FAULTS, lambda: None), LossAudit(StreamStats()),
                                 random.Random(seed))  # fmt: skip
        return [injector.next_kind() for _ in range(2 * len(FAULTS))]

    first = order(7)
    assert sorted(first[: len(FAULTS)]) == sorted(FAULTS) == sorted(first[len(FAULTS) :])
    assert first == order(7)
    assert first != order(8)


def test_memory_growth_is_the_second_halfs_trend():
    mib = 1 << 20
    flat = [(t, 200 * mib + (t % 2) * mib) for t in range(0, 61)]  # warm noise, no trend
    leak = [(t, 200 * mib + t * mib // 2) for t in range(0, 61)]  # 0.5 MiB a second
    warm = [(t, (100 + min(t, 20) * 5) * mib) for t in range(0, 61)]  # grows, then flat
    assert abs(growth(flat).second_half_growth_b) < 0.1 * mib
    assert growth(leak).second_half_growth_b == pytest.approx(15 * mib)
    assert growth(warm).second_half_growth_b == pytest.approx(0.0)
    assert (growth(warm).start_b, growth(warm).peak_b) == (100 * mib, 200 * mib)


def test_a_short_soak_accounts_for_every_lost_frame(tmp_path, capsys):
    rrd = tmp_path / "soak.rrd"
    code = main(
        ["soak", "--minutes", "0.1", "--fast", "--fault-every", "0.3", "--seed", "2",
         "--max-growth-mib", "1000", "--save", str(rrd), "--segment-mb", "2"]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    injected = re.findall(r"\] fault: (.+)", out)
    assert injected
    assert set(injected) <= set(FAULTS)
    lost = int(re.search(r"camera: received \d+ frames; lost (\d+)", out).group(1))
    accounted, total = (int(x) for x in re.search(r"\((\d+) of (\d+) accounted", out).groups())
    assert accounted == total == lost
    booked = {m.group(1): int(m.group(2)) for m in re.finditer(r"  (.+): injected (\d+),", out)}
    for kind in set(injected):
        assert booked[kind] == injected.count(kind)
    assert sum(int(x) for x in re.findall(r": injected \d+, lost (\d+)", out)) == lost
    assert re.search(r"latency .*: p50 [\d.]+ ms, p95 [\d.]+ ms, p99 [\d.]+ ms", out)
    assert "growth over the second half" in out
    assert "soak passed" in out
    segments = sorted(tmp_path.glob("soak-*.rrd"))  # rolled over under faults
    assert len(segments) > 1
    assert not rrd.exists()
    assert all(f.stat().st_size > 0 for f in segments)
