"""The live pipeline end to end on the emulator: the conveyor's prior, device events, closing
lines, and the pieces that keep a long run's memory flat."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
from rerun.chunk import RrdReader

from tofcut.driver.events import DeviceEvent, EventKind
from tofcut.driver.stream import StreamStats
from tofcut.tools.cli import main
from tofcut.tools.commands import record, tracking
from tofcut.tools.pipeline.latency import LatencyHistogram
from tofcut.tools.pipeline.losses import describe_losses, describe_untracked, format_ranges
from tofcut.tools.pipeline.rerun_log import STATUS_EVERY
from tofcut.tools.pipeline.run import EVENTS_QUEUED, EventRelay
from tofcut.tools.pipeline.sources import open_source
from tofcut.tracker.tracker import Tracker

BELT_MPS = 0.25
"""The conveyor scene's belt speed, along camera +x."""


def logged(path):
    """entity path → list of logged values (Scalars and TextLog text) in a recording."""
    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        for name in batch.schema.names:
            if name.startswith(("Scalars:", "TextLog:text")):
                out.setdefault(chunk.entity_path, []).extend(batch.column(name).to_pylist())
    return out


def test_live_with_the_emulated_conveyor_gives_the_tracker_the_belts_prior(
    tmp_path, capsys, monkeypatch
):
    priors = []

    class SpyTracker(Tracker):
        def update(self, frame, belt=None):
            priors.append(belt)
            return super().update(frame, belt)

    monkeypatch.setattr(tracking, "Tracker", SpyTracker)
    rrd, tracks = tmp_path / "run.rrd", tmp_path / "tracks.jsonl"
    code = main(
        ["live", "emulator:conveyor", "--fast", "--frames", "36", "--conveyor-emulator",
         "--save", str(rrd), "--tracks-out", str(tracks)]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    assert len(priors) == 36
    informed = [p for p in priors if p is not None and p.informed]
    # the run waited for the link's first reading: at most a frame exposed before it (the
    # emulated camera's clock starts when it is opened) goes without; none after
    first = next(k for k, p in enumerate(priors) if p is not None and p.informed)
    assert len(informed) == 36 - first >= 30
    for p in informed:
        np.testing.assert_allclose(p.mean, [BELT_MPS, 0.0, 0.0], atol=1e-9)
        # The conveyor's prior, not the scene's fixed isotropic one: tight along the belt.
        assert p.cov[0, 0] < p.cov[1, 1]
    # The tracks ride the belt: their filtered velocities follow its speed.
    frames = [json.loads(x) for x in tracks.read_text().splitlines()]
    late = [t["velocity"] for f in frames[-10:] for t in f["tracks"]]
    assert late
    assert np.median([v[0] for v in late]) == pytest.approx(BELT_MPS, abs=0.03)
    # The belt's speed reached rerun with the health, every STATUS_EVERY-th frame.
    speeds = [v[0] for v in logged(rrd)["/status/belt_speed_mps"]]
    assert len(speeds) >= 30 // STATUS_EVERY
    assert speeds == pytest.approx([BELT_MPS] * len(speeds))
    assert "tracked 36 frames" in out
    assert "; lost 0;" in out
    line = next(x for x in out.splitlines() if x.startswith("conveyor /dev/"))
    polls = line.split(": ", 1)[1].split(" polls")[0]
    done, asked = (int(x) for x in polls.split("/"))
    assert done == asked > 0
    assert "0 reopens" in line


def test_rejects_reach_rerun_as_events(tmp_path, capsys):
    rrd = tmp_path / "run.rrd"
    code = main(
        ["live", "emulator:conveyor", "--fast", "--frames", "30", "--conveyor-emulator",
         "--reject", "height > 0.0", "--diverter-distance", "0.1", "--save", str(rrd)]
    )  # fmt: skip
    assert code == 0
    out = capsys.readouterr().out
    fired = int(out.split("rejects: ")[1].split(" fired")[0])
    assert fired > 0
    texts = [t[0] for t in logged(rrd).get("/events/device", [])]
    rejects = [t for t in texts if t.startswith("reject track")]
    assert len(rejects) == fired


def test_the_conveyor_options_need_a_live_camera(tmp_path, capsys):
    cap = tmp_path / "run.tofcap"
    assert main(["record", "emulator:test-pattern", "-o", str(cap), "--frames", "3", "--fast"]) == 0
    assert main(["track", str(cap), "--conveyor-emulator", "--save", str(tmp_path / "r.rrd")]) == 1
    assert "need a live camera" in capsys.readouterr().err


def test_the_event_relay_hands_on_every_event_in_order_off_the_posting_thread():
    seen: list[tuple[str, str]] = []
    relay = EventRelay()
    events = [DeviceEvent(EventKind.STALL_CLEARED, i, f"stall {i}") for i in range(50)]
    relay.post(events[0])  # before start: kept, not lost
    relay.start([lambda e: seen.append((e.detail, threading.current_thread().name))])
    poster = threading.Thread(target=lambda: [relay.post(e) for e in events[1:]])
    poster.start()
    poster.join()
    relay.close()
    assert [d for d, _ in seen] == [e.detail for e in events]
    assert {name for _, name in seen} == {"tofcut-events"}


def test_the_event_relay_keeps_at_most_its_bound_and_counts_the_rest():
    relay = EventRelay()
    n = EVENTS_QUEUED + 300
    for i in range(n):  # nothing takes them yet: a stuck console, or before start
        relay.post(DeviceEvent(EventKind.STALL_CLEARED, i, f"stall {i}"))
    assert relay.dropped == 300
    seen: list[str] = []
    relay.start([lambda e: seen.append(e.detail)])
    relay.close()
    assert seen == [f"stall {i}" for i in range(EVENTS_QUEUED)]


def test_after_a_handler_failed_the_relay_drains_what_is_posted():
    relay = EventRelay().start([lambda e: (_ for _ in ()).throw(OSError("console gone"))])
    for i in range(3 * EVENTS_QUEUED):
        relay.post(DeviceEvent(EventKind.RESET, i, "reset"))
    with pytest.raises(OSError, match="console gone"):
        relay.close()
    assert relay._queue.qsize() == 0


def test_the_event_relay_raises_what_a_handler_raised_at_close():
    relay = EventRelay().start([lambda e: (_ for _ in ()).throw(OSError("console gone"))])
    relay.post(DeviceEvent(EventKind.RESET, 0, "reset"))
    with pytest.raises(OSError, match="console gone"):
        relay.close()


def test_the_closing_lines_say_what_was_counted_and_what_estimated():
    stats = StreamStats(frames=500, damaged=1, reconnects=2, device_dropped_flags=1)
    stats.record_gap(10, 12)
    stats.record_gap(100, 136, estimated=True)
    stats.record_gap(300, 300)
    first, ranges = describe_losses(stats)
    assert first == (
        "received 500 frames; lost 41 (4 counted from sequence numbers, 37 estimated from "
        "outage time); 1 damaged; 2 reconnects; "
        "1 frames came flagged after a FIFO overflow"
    )
    assert ranges == "lost sequence numbers: 10-12, 100-136 (estimated), 300"
    assert format_ranges([(1, 1), (3, 4), (8, 9)], limit=2) == "1 earlier ranges, then 3-4, 8-9"
    assert describe_losses(StreamStats(frames=3)) == ["received 3 frames; lost 0; 0 damaged"]


def test_frames_received_but_not_tracked_when_the_run_stopped_are_said():
    # `tofcut live` for 10 s: 501 received, 499 tracked, none dropped; 2 still queued
    assert describe_untracked(501, 499, 0) == "received but not tracked when the run stopped: 2"
    assert describe_untracked(500, 490, 10) is None


def test_latency_percentiles_are_within_two_percent_in_constant_memory():
    rng = np.random.default_rng(5)
    values = rng.lognormal(np.log(0.03), 0.6, 20_000)
    hist = LatencyHistogram()
    for v in values:
        hist.add(float(v))
    for q in (50, 95, 99, 100):
        exact = float(np.percentile(values, q, method="inverted_cdf"))
        assert exact <= hist.percentile(q) <= exact * 1.02
    assert hist.count == 20_000
    size = hist._counts.nbytes
    for v in values:
        hist.add(float(v))
    assert hist._counts.nbytes == size  # nothing kept per frame
    assert LatencyHistogram().percentile(99) == 0.0
    with pytest.raises(ValueError, match="not a number"):
        hist.add(float("nan"))


def test_live_survives_an_unplug_and_a_stall_and_says_so(tmp_path, capsys, monkeypatch):
    """Device events reach rerun and the console; the closing lines count the losses."""
    faults_done = threading.Event()

    def open_with_faults(spec, **kw):
        opened = open_source(spec, **kw)
        bus, emu = opened.bus, opened.emulator
        emu.stall_endpoint()  # the first read stalls: cleared, read on
        emu.damage_next("truncate")  # a frame cut short: damaged, lost

        def unplug_for_a_while():
            bus.unplug(emu)
            threading.Timer(0.3, lambda: (bus.replug(emu), faults_done.set())).start()

        threading.Timer(0.5, unplug_for_a_while).start()
        return opened

    monkeypatch.setattr(tracking, "open_source", open_with_faults)
    rrd = tmp_path / "run.rrd"
    code = main(["live", "emulator:conveyor", "--fast", "--seconds", "2.5", "--save", str(rrd)])
    assert code == 0
    assert faults_done.is_set()
    captured = capsys.readouterr()
    texts = [t[0] for t in logged(rrd).get("/events/device", [])]
    for kind in ("stall-cleared", "disconnected", "reconnected", "resumed"):
        assert any(t.startswith(kind + ":") for t in texts), (kind, texts)
        assert f"device: {kind}:" in captured.err
    losses = next(x for x in captured.out.splitlines() if x.startswith("received "))
    assert "1 damaged" in losses
    assert "1 reconnects" in losses
    assert "lost sequence numbers: " in captured.out


@pytest.mark.parametrize("reconnect", [False, True])
def test_record_fails_fast_unless_asked_to_reconnect(tmp_path, capsys, monkeypatch, reconnect):
    def open_then_unplug_at_frame_5(spec, **kw):
        opened = open_source(spec, **kw)
        emu, bus = opened.emulator, opened.bus
        seen = 0

        def count_and_unplug(raw):
            nonlocal seen
            seen += 1
            if seen == 5:
                bus.unplug(emu)
                threading.Timer(0.2, lambda: bus.replug(emu)).start()

        original = opened.device.raw_frames

        def raw_frames(*a, **k):
            for raw in original(*a, **k):
                count_and_unplug(raw)
                yield raw

        opened.device.raw_frames = raw_frames
        return opened

    monkeypatch.setattr(record, "open_source", open_then_unplug_at_frame_5)
    cap = tmp_path / "run.tofcap"
    argv = ["record", "emulator:test-pattern", "-o", str(cap), "--frames", "12", "--fast"]
    code = main(argv + (["--reconnect"] if reconnect else []))
    captured = capsys.readouterr()
    if not reconnect:
        assert code == 1
        assert "gone" in captured.err  # Disconnected, with the USB error
        return
    assert code == 0
    assert "device: disconnected:" in captured.err
    assert "device: reconnected:" in captured.err
    assert "1 reconnects" in captured.out
    assert "wrote " in captured.out
