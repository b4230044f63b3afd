"""`tofcut convert` through the command line: each output opened with its own library
(plyfile, pypcd4, Pillow) and held to the capture's frames."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from plyfile import PlyData
from pypcd4 import PointCloud

from tofcut.driver.calibration import parse_calibration, pixel_rays
from tofcut.driver.capture import CaptureReader
from tofcut.tools.cli import main

THRESHOLD = "300"
"""Amplitude threshold that leaves some pixels invalid in the emulated scene."""


@pytest.fixture(scope="module")
def capture(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cap") / "x.tofcap"
    assert main(["record", "emulator", "--frames", "5", "--fast", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def frames(capture):
    frames = list(CaptureReader(capture, amplitude_threshold=float(THRESHOLD)).frames())
    assert len(frames) == 5
    invalid = sum(int((~f.valid).sum()) for f in frames)
    assert 0 < invalid < sum(f.valid.size for f in frames) // 2  # the test needs both kinds
    return frames


def convert(capture: Path, out: Path, *extra: str) -> None:
    argv = ["convert", str(capture), "-o", str(out), "--amplitude-threshold", THRESHOLD]
    assert main([*argv, *extra]) == 0


def expected_points(frame):
    return frame.xyz[frame.valid].astype(np.float32), frame.amplitude[frame.valid]


def test_ply_per_frame_holds_the_valid_points_and_their_amplitude(capture, frames, tmp_path):
    out = tmp_path / "clouds"
    convert(capture, out, "--format", "ply")
    files = sorted(out.iterdir())
    assert [f.name for f in files] == [f"frame-{i:06d}.ply" for i in range(5)]
    for path, frame in zip(files, frames, strict=True):
        ply = PlyData.read(str(path))
        assert not ply.text  # binary
        assert ply.byte_order == "<"
        vertex = ply["vertex"]
        xyz, amplitude = expected_points(frame)
        assert vertex.count == len(xyz) == int(frame.valid.sum())
        got = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=-1)
        np.testing.assert_array_equal(got, xyz)
        np.testing.assert_allclose(vertex["amplitude"], amplitude, rtol=1e-6)


def test_pcd_one_frame_by_its_extension(capture, frames, tmp_path):
    out = tmp_path / "three.pcd"
    convert(capture, out, "--frame", "3")
    assert b"DATA binary\n" in out.read_bytes()[:400]
    cloud = PointCloud.from_path(out)
    assert cloud.fields == ("x", "y", "z", "amplitude")
    xyz, amplitude = expected_points(frames[3])
    np.testing.assert_array_equal(cloud.numpy(("x", "y", "z")), xyz)
    np.testing.assert_allclose(cloud.numpy(("amplitude",))[:, 0], amplitude, rtol=1e-6)
    assert [p.name for p in tmp_path.iterdir()] == ["three.pcd"]


def test_depth_png_is_z_in_millimetres_with_intrinsics_beside_it(capture, frames, tmp_path):
    out = tmp_path / "depth"
    convert(capture, out, "--format", "png")
    for i, frame in enumerate(frames):
        path = out / f"frame-{i:06d}.png"
        assert path.read_bytes()[24] == 16  # IHDR bit depth: a 16-bit PNG
        with Image.open(path) as image:
            depth = np.asarray(image).astype(np.int64)
        assert depth.shape == frame.valid.shape
        assert (depth[~frame.valid] == 0).all()
        z_mm = frame.xyz[..., 2] * 1000
        # A valid pixel whose z rounds below 1 mm (a phase wrapped near 0) is 0 as well.
        shown = frame.valid & (z_mm >= 0.5)
        assert np.abs(depth[shown] - z_mm[shown]).max() <= 0.5 + 1e-6
        assert (depth[~shown] == 0).all()
    info = json.loads((out / "intrinsics.json").read_text())
    calib = parse_calibration(CaptureReader(capture).capture.calibration_block)
    assert (info["width"], info["height"]) == (calib.width, calib.height)
    ros = info["camera_info"]
    assert ros["distortion_model"] == "plumb_bob"
    np.testing.assert_allclose(ros["D"], calib.distortion)
    np.testing.assert_allclose(ros["K"], [calib.fx, 0, calib.cx, 0, calib.fy, calib.cy, 0, 0, 1])
    # The fitted pinhole back-projects every pixel within the residual it states.
    rays = pixel_rays(calib)
    v, u = np.mgrid[0 : calib.height, 0 : calib.width]
    x = (u - info["cx"]) / info["fx"] - rays[..., 0] / rays[..., 2]
    y = (v - info["cy"]) / info["fy"] - rays[..., 1] / rays[..., 2]
    fit = info["pinhole_fit"]
    assert np.hypot(x, y).max() * 1000 == pytest.approx(fit["max_lateral_mm_per_m"])
    assert 0 < fit["rms_px"] < fit["max_px"] < 5  # the emulated lens has distortion
    k = np.array(info["intrinsic_matrix"]).reshape(3, 3, order="F")  # Open3D: column-major
    np.testing.assert_allclose(
        k, [[info["fx"], 0, info["cx"]], [0, info["fy"], info["cy"]], [0, 0, 1]]
    )


def test_npz_carries_the_calibration(capture, frames, tmp_path):
    out = tmp_path / "x.npz"
    convert(capture, out)
    with np.load(out, allow_pickle=False) as npz:
        np.testing.assert_array_equal(npz["valid"], [f.valid for f in frames])
        np.testing.assert_allclose(npz["range"], [f.range for f in frames], rtol=1e-6)
        calib = parse_calibration(npz["calibration_block"].tobytes())
        np.testing.assert_allclose(npz["D"], calib.distortion)
        assert npz["K"][0, 0] == pytest.approx(calib.fx)
        assert str(npz["distortion_model"]) == "plumb_bob"
        assert json.loads(str(npz["intrinsics_json"]))["camera_info"]["D"] == list(npz["D"])


@pytest.mark.parametrize(
    ("output", "extra", "says"),
    [
        ("x.xyz", [], "unknown extension '.xyz'"),
        ("plain", [], "cannot tell which format"),
        ("gone/x.ply", [], "folder gone does not exist"),
        ("x.ply", ["--frame", "5"], "--frame 5 is out of range"),
        ("x.npz", ["--frame", "-1"], "--frame -1 is out of range"),
    ],
)
def test_mistakes_are_one_line(capsys, capture, tmp_path, monkeypatch, output, extra, says):
    monkeypatch.chdir(tmp_path)
    code = None
    try:
        code = main(["convert", str(capture), "-o", output, *extra])
    except SystemExit as exc:
        code = exc.code
    assert code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].startswith("tofcut: error: ")
    assert says in lines[0], lines[0]
    assert list(tmp_path.iterdir()) == []
