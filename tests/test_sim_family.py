"""The conveyor family: lines drawn from a seed, their scene files, their ground truth, and the
command line that draws them (docs/family.md)."""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
import tomllib
from collections import Counter
from typing import Any

import numpy as np
import pytest

from tofcut.driver.calibration import pixel_rays
from tofcut.driver.protocol import integration_us
from tofcut.sim import load_truth, open_scene
from tofcut.sim.device import READOUT_US
from tofcut.sim.family import (
    HEIGHT_STEP_MM,
    KINDS,
    MAX_HALF_SPAN_M,
    SLAB_TOP_M,
    ConveyorLine,
    LineObject,
    draw_conveyor,
    parse_family_name,
)
from tofcut.sim.preview import scene_exposure
from tofcut.sim.renderer import SceneSource
from tofcut.sim.scene_file import SceneError, load_scene
from tofcut.tools.cli import main
from tofcut.tools.pipeline.sources import SourceSpec

COVER = range(200)
"""Seeds whose draws must cover every range."""
RENDERED = {
    8: "a camera tilted 59.2° that starts full",
    25: "a camera looking straight down (tilt 0.0) on a line that starts empty and may saturate",
    49: "a slow belt (0.057 m/s) that starts empty",
}
"""Seeds rendered, and why each is here."""
DIGESTS = {
    0: "704d8375d153f2b50730ed5dadf3457392759a8f4cbd790c1003e7b502a75cdd",
    17: "c295ce1e15d5b314b195ac14969d3e7511a344fd46ac075144b03e7cc006e745",
    1000: "385701ba5156a0089677422fc5e2cd2ffd9bebaf0d1cc67c6ba9f8a6ebe2a96b",
}
"""sha256 of the TOML these seeds draw. The family is a benchmark: a change here changes every
tuning and held-out line, so it needs `FAMILY_VERSION` bumped and a word in docs/family.md."""


@pytest.fixture(scope="module")
def lines() -> list[ConveyorLine]:
    return [draw_conveyor(seed) for seed in COVER]


def same(a: Any, b: Any, where: str = "scene") -> None:
    """Two scene values are equal field by field (arrays exactly)."""
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        assert type(a) is type(b), where
        for f in dataclasses.fields(a):
            same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, np.ndarray):
        assert np.array_equal(a, b), where
    elif isinstance(a, tuple | list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same(x, y, f"{where}[{i}]")
    else:
        assert a == b, f"{where}: {a!r} != {b!r}"


# --- determinism and the scene file ---------------------------------------------------------


def test_the_same_seed_draws_the_same_line_bit_for_bit():
    first, again = draw_conveyor(17), draw_conveyor(17)
    assert first == again
    assert first.toml() == again.toml()
    assert draw_conveyor(18).toml() != first.toml()
    for seed, digest in DIGESTS.items():
        text = draw_conveyor(seed).toml()
        assert hashlib.sha256(text.encode()).hexdigest() == digest, seed


def test_a_line_written_out_loads_back_as_the_same_scene(tmp_path):
    line = draw_conveyor(8)
    text = line.toml()
    assert tomllib.loads(text) == line.document()
    path = tmp_path / "line.toml"
    path.write_text(text, encoding="utf-8")
    loaded = load_scene(path)
    same(loaded, line.scene())  # every field, every array exactly: it renders the same
    assert loaded.name == "family-conveyor-8"
    assert loaded.duration_s == line.loop_m / line.belt_speed_mps


def test_an_edited_scene_file_is_a_scene_file(tmp_path):
    path = tmp_path / "edited.toml"
    text = draw_conveyor(3).toml().replace("speed = 0.288", "speed = 0.4")
    path.write_text(text, encoding="utf-8")
    belt = load_scene(path).belt  # what emulator:FILE.toml opens
    assert belt is not None
    assert belt.speed_mps == 0.4


# --- what the family draws -------------------------------------------------------------------


def near(values: list[float], lo: float, hi: float, share: float = 0.03) -> None:
    """The values stay within lo..hi and reach within `share` of the span of both ends."""
    tol = share * (hi - lo)
    assert lo - 1e-9 <= min(values) <= lo + tol, (min(values), lo)
    assert hi - tol <= max(values) <= hi + 1e-9, (max(values), hi)


def test_seeds_0_to_199_cover_every_range(lines):
    near([x.camera_height_m for x in lines], 1.0, 2.5)
    near([x.tilt_deg for x in lines], 0.0, 60.0)
    near([x.yaw_deg for x in lines], 0.0, 360.0)
    near([x.belt_speed_mps for x in lines], 0.05, 0.6)
    near([x.belt_albedo for x in lines], 0.15, 0.8)
    near([x.belt_width_m for x in lines], 0.4, 1.0)
    near([x.floor_drop_m for x in lines], 0.5, 1.2)
    near([x.ambient for x in lines], 20.0, 300.0)
    near([x.integration_ms for x in lines], 2.0, 8.0)
    assert {x.mod_freq_mhz for x in lines} == {15.0, 30.0}
    assert {x.fps for x in lines} == {25, 50}
    assert Counter(x.look_alike for x in lines).keys() == {True, False}
    assert Counter(x.start_full for x in lines).keys() == {True, False}
    assert {x.enters_from for x in lines} == {"left", "top", "right", "bottom"}
    assert max(x.duration_s for x in lines) > 20.0  # long loops, slow belts
    objects = [o for x in lines for o in x.objects]
    assert {o.kind for o in objects} == set(KINDS)
    near([o.height_m for o in objects if o.kind == "box"], 0.04, 0.30)
    near([o.height_m for o in objects if o.kind == "bag"], 0.04, 0.12)
    near([o.height_m for o in objects if o.kind == "can"], 0.06, 0.30)
    near([o.height_m for o in objects if o.kind == "roll"], 0.04, 0.30)
    kinds = Counter(c.kind for x in lines for c in x.contacts())
    assert kinds["side"] >= 100, kinds
    assert kinds["nose"] >= 100, kinds


def test_every_line_keeps_its_rules(lines):
    for x in lines:
        heights = {o.name: o.height_m for o in x.objects}
        for c in x.contacts():  # touching or near: range can part them
            assert abs(heights[c.a] - heights[c.b]) >= HEIGHT_STEP_MM / 1000 - 1e-9, (x.seed, c)
        for o in x.objects:
            if x.look_alike:
                assert abs(o.albedo - x.belt_albedo) <= 0.05 + 1e-9
            else:
                assert abs(o.albedo - x.belt_albedo) >= 0.15 - 1e-9
            y0, y1 = o.span_m(1)
            assert -x.belt_width_m / 2 < y0 < y1 < x.belt_width_m / 2
            assert x.loop_start_m <= o.position_m[0] < x.loop_start_m + x.loop_m
        # the camera can take its four taps within a frame
        assert 4 * (integration_us(x.integration) + READOUT_US) <= 1e6 / x.fps
        assert 2.0 - 1e-9 <= x.integration_ms <= 8.0 + 1e-9
        # the wrap is out of view: the view's footprint and an object's half-span either side
        assert x.loop_start_m + MAX_HALF_SPAN_M < x.view_x_m[0]
        assert x.view_x_m[1] < x.loop_start_m + x.loop_m - MAX_HALF_SPAN_M
        assert x.first_in_view_s <= 8.0 + 1e-6


def empty_stretches(line: ConveyorLine) -> list[float]:
    """Lengths of belt, round the loop, on which no object lies anywhere across it."""
    spans = sorted(o.span_m(0) for o in line.objects)
    merged: list[list[float]] = []
    for a, b in spans:
        if merged and a <= merged[-1][1] + 1e-9:
            merged[-1][1] = max(merged[-1][1], b)
        else:
            merged.append([a, b])
    gaps = [b[0] - a[1] for a, b in itertools.pairwise(merged)]
    return [*gaps, merged[0][0] + line.loop_m - merged[-1][1]]


def test_gaps_along_the_belt_are_0_to_30_cm(lines):
    """A full line has no empty stretch longer than 30 cm; an empty one has one, its start."""
    every = []
    for x in lines:
        gaps = sorted(empty_stretches(x))
        if not x.start_full:
            assert gaps.pop() > x.view_x_m[1] - x.view_x_m[0]
        assert all(g <= 0.3 + 1e-9 for g in gaps), (x.seed, gaps)
        every += gaps
    assert max(every) > 0.29


# --- rendered --------------------------------------------------------------------------------


def belt_pixels(source: SceneSource, line: ConveyorLine, labels: Any, range_m: Any) -> int:
    """Background pixels whose true surface is the belt's top (z = 0, within its width)."""
    rays = pixel_rays(source.calibration)
    world = source.scene.camera_from_world.inverse()
    points = world.apply(rays * range_m[..., None])
    top = (np.abs(points[..., 2]) < 1e-6) & (np.abs(points[..., 1]) <= line.belt_width_m / 2)
    return int((top & (labels == 0)).sum())


@pytest.mark.parametrize("seed", sorted(RENDERED))
def test_a_drawn_line_renders_as_drawn(seed):
    line = draw_conveyor(seed)
    source = SceneSource(line.scene())
    assert source.name == f"family-conveyor-{seed}"
    assert seed != 25 or (line.tilt_deg == 0.0 and line.may_saturate)
    # t = 0, as the emulated camera takes it: objects in view on a full line, none on an empty
    rendered = source.render(scene_exposure(source, 0.0))
    truth = rendered.truth
    assert rendered.taps.shape == (4, 144, 176)
    assert np.isfinite(truth.range).all()
    shown = sum(o.pixels for o in truth.objects)
    assert (shown > 0) == line.start_full, shown
    assert belt_pixels(source, line, truth.labels, truth.range) > 0.02 * truth.labels.size
    # objects are in view within the first 20 s
    later = source.truth_at(line.first_in_view_s + 2.0)
    assert line.first_in_view_s + 2.0 < 20.0
    assert sum(o.pixels for o in later.objects) > 0
    # the wrap is never in view: no pixel sees the belt (up to the tallest objects) within an
    # object's half-span of either wrap point ...
    rays = pixel_rays(source.calibration).reshape(-1, 3)
    world = source.scene.camera_from_world.inverse()
    origin = world.translation
    dirs = rays @ world.rotation.T
    for z in np.linspace(0.0, SLAB_TOP_M, 7):
        hit = origin + dirs * ((z - origin[2]) / dirs[:, 2])[:, None]
        on_belt = np.abs(hit[:, 1]) <= line.belt_width_m / 2
        x = hit[on_belt, 0]
        assert (x > line.loop_start_m + MAX_HALF_SPAN_M).all()
        assert (x < line.loop_start_m + line.loop_m - MAX_HALF_SPAN_M).all()
    # ... and the longest object is unseen as it wraps
    obj = max(line.objects, key=lambda o: o.footprint_m[0])
    index = line.objects.index(obj) + 1
    wrap_s = (line.loop_start_m + line.loop_m - obj.position_m[0]) / line.belt_speed_mps
    for t in (wrap_s - 0.02, wrap_s + 0.02):
        assert source.truth_at(t).object(index).pixels == 0


# --- names and the command line --------------------------------------------------------------


def test_a_family_line_is_a_scene_name_for_the_emulator():
    assert parse_family_name("family:conveyor:17") == ("conveyor", 17)
    assert parse_family_name("conveyor") is None
    assert SourceSpec.parse("emulator:family:conveyor:17").arg == "family:conveyor:17"
    for bad in ("family:conveyor", "family:conveyor:-3", "family:conveyor:1.5", "family:belt:2"):
        with pytest.raises(SceneError, match="family"):
            open_scene(bad)


def test_values_are_checked():
    with pytest.raises(SceneError, match="seed"):
        draw_conveyor(-1)
    line = draw_conveyor(5)
    with pytest.raises(SceneError, match="aim at the belt"):
        dataclasses.replace(line, aim_offset_m=line.belt_width_m)
    with pytest.raises(SceneError, match="fps"):
        dataclasses.replace(line, fps=60)
    with pytest.raises(SceneError, match="kind"):
        dataclasses.replace(line.objects[0], kind="crate")
    twin = dataclasses.replace(line.objects[0], name="twin")
    crowded = dataclasses.replace(line, objects=(line.objects[0], twin))
    with pytest.raises(SceneError, match="overlap"):
        crowded.contacts()
    assert isinstance(twin, LineObject)


def test_scenes_command_draws_a_family_line(tmp_path, capsys):
    toml = tmp_path / "line.toml"
    assert main(["scenes", "--family", "conveyor", "--seed", "17", "--toml-out", str(toml),
                 "--out", str(tmp_path)]) == 0  # fmt: skip
    out = capsys.readouterr().out
    line = draw_conveyor(17)
    assert out.startswith("family-conveyor-17 (tuning seed): camera 2.268 m above the belt")
    assert " ".join(out.split()).startswith(line.summary())
    assert toml.read_text(encoding="utf-8") == line.toml()
    assert (tmp_path / "family-conveyor-17.png").stat().st_size > 1000
    assert main(["scenes", "--family", "conveyor", "--seed", "1000"]) == 0
    assert "held-out seed" in capsys.readouterr().out


def test_scenes_command_without_family_refuses_its_options(tmp_path, capsys):
    assert main(["scenes", "--toml-out", str(tmp_path / "x.toml")]) == 1
    assert "--family" in capsys.readouterr().err
    assert main(["scenes", "conveyor", "--family", "conveyor"]) == 1
    assert not (tmp_path / "x.toml").exists()


def test_record_a_family_line_from_the_emulator(tmp_path, capsys):
    path = tmp_path / "run.tofcap"
    args = ["record", "emulator:family:conveyor:17", "--fast", "--frames", "3", "-o", str(path)]
    assert main(args) == 0
    assert "3 frames" in capsys.readouterr().out
    truth = load_truth(tmp_path / "run.truth.npz")
    assert len(truth) == 3
    assert math.isclose(truth[1].time_s - truth[0].time_s, 1 / 25)  # the line's 25 fps
    assert [o.name for o in truth[0].objects] == [o.name for o in draw_conveyor(17).objects]
