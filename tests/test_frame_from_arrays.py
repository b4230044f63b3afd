"""The tracker's input from any depth source: `Frame.from_arrays` and `Intrinsics`.

The emulated conveyor is turned into plain arrays and rebuilt: with everything tofcut's own
frames hold (range and points, amplitude, intensity, validity, times) the rebuilt frames
are the same frames, and track the same to the bit; with only what another depth camera
gives (range, amplitude, a pinhole's intrinsics) they track about as well against the
emulator's ground truth, and close to the original tracks.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import json
from pathlib import Path

import motmetrics as mm
import numpy as np
import pytest

import tofcut
from tofcut.driver.calibration import pixel_rays
from tofcut.driver.errors import FrameInputError, TofcutError
from tofcut.driver.intrinsics import Intrinsics
from tofcut.testing import emulated_camera
from tofcut.tools.evaluation.scoring import evaluate
from tofcut.tools.pipeline import export

ROOT = Path(__file__).resolve().parents[1]
FRAMES = 100
"""2 s of the conveyor at 50 fps: boxes enter, cross and leave."""
PINHOLE = Intrinsics(width=4, height=3, fx=2.0, fy=2.5, cx=1.5, cy=1.0)


@pytest.fixture(scope="module")
def conveyor():
    """The emulated conveyor (fast, seed 0): frames, their ground truth, the belt, the
    lens's rays, and the intrinsics.json `tofcut convert` writes for it (a pinhole fitted to
    the lens: 0.57 px rms, at most 10.8 mm per metre of depth off sideways)."""
    with emulated_camera("conveyor", seed=0) as camera:
        frames, truths = [], []
        for frame in camera.frames(count=FRAMES):
            frames.append(frame)
            truths.append(camera.truth(frame.sequence))
        calib = camera.camera.calibration
        intrinsics_json = json.dumps(export.intrinsics(calib))
        return frames, truths, camera.belt, pixel_rays(calib), intrinsics_json


def track(frames, belt):
    """Each frame's tracks (id → centroid) and the masks, by sequence number."""
    tracker = tofcut.Tracker(belt=belt)
    tracks, masks = [], {}
    for frame in frames:
        tracked = tracker.update(frame)
        tracks.append({t.id: t.centroid for t in tracked.tracks})
        masks[frame.sequence] = tracked.labels
    return tracks, masks


def scores(frames, truths, belt, rays):
    """MOTA and IDF1 against the emulator's ground truth, by 3D centroid (0.1 m gate)."""
    tracks, masks = track(frames, belt)
    by_seq = {
        f.sequence: [{"id": i, "centroid": c.tolist()} for i, c in t.items()]
        for f, t in zip(frames, tracks, strict=True)
    }
    s = evaluate(truths, by_seq, masks, rays).by_centroid
    return s.mota, s.idf1


def agreement(reference, other, gate_m=0.05):
    """MOTA and IDF1 of `other`'s tracks taking `reference`'s as the truth (centroids
    within `gate_m`), and the matched centroids' distances (m)."""
    acc = mm.MOTAccumulator(auto_id=True)
    distances = []
    for a, b in zip(reference, other, strict=True):
        ids_a, ids_b = sorted(a), sorted(b)
        pa = np.array([a[i] for i in ids_a]).reshape(-1, 3)
        pb = np.array([b[i] for i in ids_b]).reshape(-1, 3)
        d2 = mm.distances.norm2squared_matrix(pa, pb, max_d2=gate_m**2)
        acc.update(ids_a, ids_b, d2)
        distances += list(np.sqrt(d2[np.isfinite(d2)]))
    table = mm.metrics.create().compute(acc, metrics=["mota", "idf1"])
    return float(table["mota"].iloc[0]), float(table["idf1"].iloc[0]), np.array(distances)


def usable(frame):
    """A tofcut frame's validity as `from_arrays` takes it: a pixel whose phase wrapped round
    reads a range just below 0 (19 of 2.5 million here), which a valid pixel may not have."""
    return frame.valid & (frame.range > 0)


# --- tracking from plain arrays -------------------------------------------------------------


def test_everything_a_tofcut_frame_holds_rebuilds_the_same_frame_and_the_same_tracks(conveyor):
    frames, _, belt, _, _ = conveyor
    originals = [dataclasses.replace(f, valid=usable(f)) for f in frames]
    rebuilt = [
        tofcut.Frame.from_arrays(
            range_m=f.range,
            xyz=f.xyz,
            amplitude=f.amplitude,
            intensity=f.intensity,
            valid=usable(f),
            time_s=f.device_time_us / 1e6,
            sequence=f.sequence,
            host_time_ns=f.host_time_ns,
        )
        for f in frames
    ]
    for a, b in zip(originals, rebuilt, strict=True):
        for name in ("range", "xyz", "amplitude", "intensity", "valid"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        assert (a.sequence, a.device_time_us, a.host_time_ns, a.shape) == (
            b.sequence,
            b.device_time_us,
            b.host_time_ns,
            b.shape,
        )
    tracks_a, masks_a = track(originals, belt)
    tracks_b, masks_b = track(rebuilt, belt)
    assert tracks_a[-1], "the conveyor's boxes are tracked"
    for a, b in zip(tracks_a, tracks_b, strict=True):
        assert a.keys() == b.keys()
        for i in a:
            np.testing.assert_array_equal(a[i], b[i])
    for seq, labels in masks_a.items():
        np.testing.assert_array_equal(labels, masks_b[seq])


def test_range_amplitude_and_a_pinhole_track_about_as_well_as_the_camera_frames(conveyor):
    """What another depth camera gives: range along the rays (NaN where it has none), an
    amplitude, and a pinhole's intrinsics (here read back from `intrinsics.json`). Not the
    same tracks, for two reasons: the pinhole is not the lens (points move sideways by up to
    10.8 mm per metre of depth, a few mm on the belt), and without an intensity the noise
    model is 1/A instead of √B/A; pixels near a threshold flip, and the tracker's
    hysteresis turns a flip into a track found a frame sooner or later. Measured (seed 0,
    100 frames): against the ground truth MOTA 0.928 → 0.942, IDF1 0.963 → 0.970; against
    the camera frames' tracks MOTA 0.980, IDF1 0.990, no switch, centroids 2.2 mm apart
    (median; 4.4 mm at the 95th percentile)."""
    frames, truths, belt, rays, intrinsics_json = conveyor
    pinhole = Intrinsics.from_json(intrinsics_json)
    plain = [
        tofcut.Frame.from_arrays(
            range_m=np.where(f.range > 0, f.range, np.nan),
            amplitude=f.amplitude,
            intrinsics=pinhole,
            time_s=f.device_time_us / 1e6,
            sequence=f.sequence,
        )
        for f in frames
    ]
    mota, idf1 = scores(frames, truths, belt, rays)
    plain_mota, plain_idf1 = scores(plain, truths, belt, rays)
    print(f"MOTA {mota:.3f} → {plain_mota:.3f}, IDF1 {idf1:.3f} → {plain_idf1:.3f}")
    assert plain_mota >= mota - 0.03
    assert plain_idf1 >= idf1 - 0.03
    agree_mota, agree_idf1, apart = agreement(track(frames, belt)[0], track(plain, belt)[0])
    print(
        f"against the camera frames' tracks: MOTA {agree_mota:.3f} IDF1 {agree_idf1:.3f}, "
        f"{np.median(apart) * 1e3:.2f} mm apart ({np.percentile(apart, 95) * 1e3:.2f} at p95)"
    )
    assert agree_mota >= 0.95
    assert agree_idf1 >= 0.95
    assert np.median(apart) <= 0.005
    assert np.percentile(apart, 95) <= 0.010


def test_depth_from_a_16_bit_png_gives_the_same_points_within_its_millimetre(conveyor):
    """Depth maps on disk: `tofcut convert --format png` writes z in mm with
    intrinsics.json beside it; read back, they give the points to within the rounding and
    the pinhole's fit."""
    frames, _, _, _, intrinsics_json = conveyor
    frame = dataclasses.replace(frames[10], valid=usable(frames[10]))
    depth = export.depth_mm(frame) / export.DEPTH_SCALE
    rebuilt = tofcut.Frame.from_arrays(
        depth_m=depth, intrinsics=Intrinsics.from_json(intrinsics_json), time_s=0.2
    )
    np.testing.assert_array_equal(rebuilt.valid, depth > 0)
    z = rebuilt.xyz[..., 2][rebuilt.valid]
    np.testing.assert_allclose(z, depth[rebuilt.valid], rtol=1e-12)
    off = np.linalg.norm(rebuilt.xyz - frame.xyz, axis=-1)[rebuilt.valid]
    assert np.percentile(off, 95) < 0.012  # the pinhole's 10.8 mm/m at ~1.4 m, and 0.5 mm


# --- the geometry ---------------------------------------------------------------------------


def test_range_depth_and_points_of_one_scene_give_one_frame():
    rays = PINHOLE.rays()
    rng = np.linspace(1.0, 2.0, 12).reshape(3, 4)
    xyz = rays * rng[..., None]
    from_range = tofcut.Frame.from_arrays(range_m=rng, intrinsics=PINHOLE, time_s=1.5)
    from_depth = tofcut.Frame.from_arrays(depth_m=xyz[..., 2], intrinsics=PINHOLE, time_s=1.5)
    from_points = tofcut.Frame.from_arrays(xyz=xyz, time_s=1.5, sequence=7, host_time_ns=3)
    for frame in (from_range, from_depth, from_points):
        np.testing.assert_allclose(frame.range, rng, rtol=1e-12)
        np.testing.assert_allclose(frame.xyz, xyz, rtol=1e-12, atol=1e-15)
        assert frame.valid.all()
        assert frame.shape == (3, 4)
        assert frame.device_time_us == 1_500_000
        np.testing.assert_array_equal(frame.phase, 0.0)
    assert (from_points.sequence, from_points.host_time_ns) == (7, 3)
    # the pinhole's rays: pixel centres at whole numbers, the principal point on the axis
    np.testing.assert_allclose(rays[1, 1] / rays[1, 1, 2], [(1 - 1.5) / 2.0, (1 - 1.0) / 2.5, 1])


def test_missing_readings_are_invalid_and_the_noise_model_has_a_default():
    rng = np.full((3, 4), 1.2)
    rng[0, 0], rng[0, 1] = np.nan, 0.0  # no reading, as depth cameras mark it
    amplitude = np.arange(12.0).reshape(3, 4) + 1
    frame = tofcut.Frame.from_arrays(
        range_m=rng, amplitude=amplitude, intrinsics=PINHOLE, time_s=0.0
    )
    assert not frame.valid[0, 0]
    assert not frame.valid[0, 1]
    assert frame.valid.sum() == 10
    assert frame.range[0, 0] == 0.0  # finite everywhere: the tracker's kernels take it
    assert np.isfinite(frame.xyz).all()
    np.testing.assert_array_equal(frame.intensity, np.median(amplitude[frame.valid]))
    bare = tofcut.Frame.from_arrays(range_m=rng, intrinsics=PINHOLE, time_s=0.0)
    np.testing.assert_array_equal(bare.amplitude, 1.0)  # every pixel equally noisy
    np.testing.assert_array_equal(bare.intensity, 1.0)


def test_frames_from_arrays_track():
    """A box on a plane, moving 5 mm a frame: one track, its velocity from `time_s`."""
    pinhole = Intrinsics(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
    rays = pinhole.rays()
    frames = []
    for k in range(12):
        z = np.full((48, 64), 1.5)
        u0 = 10 + k
        z[18:30, u0 : u0 + 12] = 1.3  # 20 cm nearer than the floor
        frames.append(
            tofcut.Frame.from_arrays(
                depth_m=z + np.random.default_rng(k).normal(0, 0.002, z.shape),
                amplitude=np.full(z.shape, 500.0),
                intrinsics=pinhole,
                time_s=k * 0.04,
                sequence=k,
            )
        )
    assert np.allclose(frames[0].range / frames[0].xyz[..., 2], 1 / rays[..., 2])
    tracker = tofcut.Tracker()
    tracked = [tracker.update(f) for f in frames]
    last = tracked[-1].tracks
    assert len(last) == 1
    # one pixel a frame at 1.3 m and fx 60: 21.7 mm per 40 ms, 0.54 m/s along +x
    assert last[0].velocity[0] == pytest.approx(1.3 / 60.0 / 0.04, rel=0.2)


# --- intrinsics -----------------------------------------------------------------------------


def test_intrinsics_read_back_what_convert_writes_and_what_open3d_and_ros_hold(conveyor):
    *_, intrinsics_json = conveyor
    written = json.loads(intrinsics_json)
    ours = Intrinsics.from_json(intrinsics_json)
    assert (ours.width, ours.height, ours.fx) == (176, 144, written["fx"])
    assert Intrinsics.from_json(ours.to_json()) == ours
    open3d = {"width": 176, "height": 144, "intrinsic_matrix": written["intrinsic_matrix"]}
    assert Intrinsics.from_json(open3d) == ours  # Open3D's own file: K column by column
    k = written["camera_info"]["K"]  # ROS: the lens's own K, row by row
    ros = Intrinsics.from_matrix(k, width=176, height=144)
    assert (ros.fx, ros.cy) == (k[0], k[5])
    np.testing.assert_array_equal(ros.matrix.ravel(), k)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (lambda: Intrinsics(width=0, height=3, fx=1, fy=1, cx=0, cy=0), "width must be a whole"),
        (lambda: Intrinsics(width=4.0, height=3, fx=1, fy=1, cx=0, cy=0), "width must be a whole"),
        (lambda: Intrinsics(width=4, height=5000, fx=1, fy=1, cx=0, cy=0), "1..4096"),
        (lambda: Intrinsics(width=4, height=3, fx=np.nan, fy=1, cx=0, cy=0), "fx must be a fin"),
        (lambda: Intrinsics(width=4, height=3, fx=1, fy=1, cx=np.inf, cy=0), "cx must be a fin"),
        (lambda: Intrinsics(width=4, height=3, fx=-1, fy=1, cx=0, cy=0), "must be positive"),
        (lambda: Intrinsics(width=4, height=3, fx="1", fy=1, cx=0, cy=0), "fx must be a finite"),
        (lambda: Intrinsics.from_matrix(np.eye(2), width=4, height=3), "K must be 3x3"),
        (
            lambda: Intrinsics.from_matrix([[1, 0.1, 0], [0, 1, 0], [0, 0, 1]], width=4, height=3),
            "no skew",
        ),
        (lambda: Intrinsics.from_matrix([["a"] * 3] * 3, width=4, height=3), "not a matrix"),
        (lambda: Intrinsics.from_json("{"), "not JSON"),
        (lambda: Intrinsics.from_json("[1]"), "must be an object"),
        (lambda: Intrinsics.from_json({"width": 4}), "needs width and height"),
        (lambda: Intrinsics.from_json({"width": 4, "height": 3}), "needs fx, fy, cx, cy or"),
        (
            lambda: Intrinsics.from_json({"width": 4, "height": 3, "intrinsic_matrix": [1, 2]}),
            "9 numbers",
        ),
    ],
)
def test_intrinsics_that_are_no_pinhole_are_one_line(make, message):
    with pytest.raises(FrameInputError, match=message) as info:
        make()
    assert "\n" not in str(info.value)


# --- every size and value checked -----------------------------------------------------------

GOOD = np.full((3, 4), 1.0)


def _bad_xyz():
    xyz = PINHOLE.rays() * 2.0
    xyz[2, 3, 2] = -1.0
    return xyz


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"range_m": None}, "give range_m, depth_m or xyz"),
        ({"range_m": GOOD, "depth_m": GOOD}, "not range_m and depth_m"),
        ({"depth_m": GOOD, "intrinsics": None}, "depth_m needs intrinsics"),
        ({"range_m": GOOD, "intrinsics": (4, 3)}, "intrinsics must be a tofcut"),
        ({"range_m": np.ones((4, 3))}, r"range_m has shape \(4, 3\), expected \(3, 4\)"),
        ({"range_m": GOOD, "amplitude": np.ones(12)}, r"amplitude has shape \(12,\)"),
        ({"range_m": GOOD.astype(str)}, "must be an array of numbers"),
        ({"range_m": [[1, 2], [3]]}, "not an array of numbers|must be an array of numbers"),
        (
            {"range_m": -GOOD},
            "range_m has negative values at 12 pixels, the first at row 0, column 0",
        ),
        ({"range_m": GOOD, "valid": np.ones((3, 4))}, "valid must be a boolean array"),
        ({"range_m": GOOD, "valid": np.ones((3, 3), bool)}, "valid must be a boolean array"),
        (
            {"range_m": np.where(GOOD > 0, np.nan, 0), "valid": np.ones((3, 4), bool)},
            "valid marks pixels without a range_m > 0",
        ),
        ({"range_m": GOOD, "amplitude": -GOOD}, "amplitude is negative"),
        ({"range_m": GOOD, "intensity": GOOD * np.nan}, "intensity is not finite at valid"),
        ({"time_s": -1.0}, "time_s must be a finite number of seconds"),
        ({"time_s": np.nan}, "time_s must be a finite number"),
        ({"time_s": "0"}, "time_s must be a finite number"),
        ({"sequence": -1}, "sequence must be a whole number"),
        ({"sequence": 1.5}, "sequence must be a whole number"),
        ({"host_time_ns": -5}, "host_time_ns must be a whole number"),
        ({"xyz": np.ones((3, 4)), "intrinsics": None}, r"xyz has shape \(3, 4\), expected"),
        ({"xyz": _bad_xyz(), "intrinsics": None}, "points behind the camera"),
        ({"xyz": [[[1, 2, 3]], [[1, 2]]], "intrinsics": None}, "xyz is not an array of numbers"),
        ({"xyz": PINHOLE.rays(), "range_m": GOOD * 2}, "xyz and range_m disagree"),
    ],
)
def test_arrays_that_cannot_make_a_frame_are_one_line(kwargs, message):
    args = {"range_m": GOOD, "intrinsics": PINHOLE, "time_s": 0.0}
    if {"xyz", "depth_m"} & kwargs.keys():
        del args["range_m"]
    args.update(kwargs)
    args = {k: v for k, v in args.items() if not (k == "intrinsics" and v is None)}
    with pytest.raises(FrameInputError, match=message) as info:
        tofcut.Frame.from_arrays(**args)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, TofcutError)
    assert isinstance(info.value, ValueError)


def test_a_negative_range_where_valid_says_no_is_left_out():
    rng = GOOD.copy()
    rng[1, 2] = -0.01  # a wrapped phase, read just below 0
    valid = rng > 0
    frame = tofcut.Frame.from_arrays(range_m=rng, valid=valid, intrinsics=PINHOLE, time_s=0.0)
    np.testing.assert_array_equal(frame.valid, valid)
    with pytest.raises(
        FrameInputError,
        match="range_m has negative values at valid pixels: 1 pixel, at row 1, column 2",
    ):
        tofcut.Frame.from_arrays(
            range_m=rng, valid=np.ones((3, 4), bool), intrinsics=PINHOLE, time_s=0.0
        )


# --- the examples for other cameras ---------------------------------------------------------


@pytest.mark.parametrize("path", sorted((ROOT / "docs" / "examples").glob("*.py")), ids=str)
def test_the_example_scripts_call_the_api_as_it_is(path):
    """docs/examples (pyk4a, pyrealsense2) cannot run here, with no such camera: they are at
    least Python, and call `Frame.from_arrays` and `Intrinsics` with arguments they have."""
    tree = ast.parse(path.read_text(), str(path))
    takes = {
        "from_arrays": set(inspect.signature(tofcut.Frame.from_arrays).parameters),
        "Intrinsics": {f.name for f in dataclasses.fields(Intrinsics)},
        "from_matrix": set(inspect.signature(Intrinsics.from_matrix).parameters),
    }
    called = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in takes:
                called.add(name)
                assert {k.arg for k in node.keywords} <= takes[name], (name, ast.dump(node))
    assert "from_arrays" in called
