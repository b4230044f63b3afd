"""`tofcut convert CAPTURE -o OUT`: a capture's frames as arrays (npz), point clouds (PLY,
PCD) or depth images (16-bit PNG with `intrinsics.json`); see `tools.pipeline.export`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from tofcut.driver.capture import CaptureReader
from tofcut.driver.demod import demodulate
from tofcut.tools.commands.arguments import UsageError, capture_file, output_file_or_folder
from tofcut.tools.commands.progress import Progress
from tofcut.tools.pipeline import export
from tofcut.tools.pipeline.losses import stats_summary

FORMATS = ("npz", "ply", "pcd", "png")

HELP = "capture → npz arrays, PLY/PCD point clouds or 16-bit depth PNGs"

DESCRIPTION = """\
The format is --format, or else OUT's extension:

  npz  one file: range, amplitude, intensity, valid, xyz (first axis: frames), seq,
       device_time_us, host_time_ns, and the calibration: K, D (k1 k2 p1 p2 k3),
       distortion_model, distance_offset_m, phase_offset (rad), calibration_block (bytes as
       the camera holds them) and intrinsics_json (as png's intrinsics.json)
  ply  point clouds, binary: x, y, z (metres; camera frame x right, y down, z forward) and
  pcd  amplitude, float32; invalid pixels are left out
  png  depth: z along the optical axis in millimetres, uint16, 0 where invalid; with
       intrinsics.json beside it (Open3D's PinholeCameraIntrinsic fields: width, height,
       fx, fy, cx, cy, intrinsic_matrix, fitted to the lens's rays, with the fit's residual;
       and camera_info: ROS's K, D, distortion_model plumb_bob, R, P, width, height, exact)

ply, pcd and png write one file per frame into the folder OUT (made if missing; its parent
must exist) as OUT/frame-000123.ply, numbered by the frame's place in the capture from 0;
with --frame N, only that frame, to OUT itself when OUT ends in the format's extension.
"""


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "convert",
        help=HELP,
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("capture", type=capture_file, metavar="CAPTURE")
    p.add_argument(
        "-o", "--output", type=output_file_or_folder, required=True, metavar="OUT",
        help="FILE.npz, FILE.ply/.pcd/.png (with --frame) or a FOLDER",
    )  # fmt: skip
    p.add_argument(
        "--format", choices=FORMATS, help="npz, ply, pcd or png (default: OUT's extension)"
    )
    p.add_argument("--frame", type=int, metavar="N", help="only frame N (0 is the capture's first)")
    p.add_argument("--amplitude-threshold", type=float, default=0.0, metavar="COUNTS")
    p.set_defaults(func=run)


def choose_format(out: Path, asked: str | None) -> str:
    """The format --format names, or OUT's extension's (a usage error if neither tells)."""
    if asked is not None:
        return asked
    suffix = out.suffix.lower().lstrip(".")
    if suffix in FORMATS:
        return suffix
    if not out.suffix or out.is_dir():
        raise UsageError(
            f"cannot tell which format to write to {out}: give --format "
            f"({', '.join(FORMATS)}) or end it in .npz, .ply, .pcd or .png"
        )
    raise UsageError(
        f"unknown extension {out.suffix!r} of {out}: use .npz, .ply, .pcd or .png (or --format)"
    )


def run(args: argparse.Namespace) -> int:
    out: Path = args.output
    fmt = choose_format(out, args.format)
    reader = CaptureReader(args.capture, amplitude_threshold=args.amplitude_threshold)
    records = len(reader)
    if args.frame is not None and not 0 <= args.frame < records:
        last = f"0 to {records - 1}" if records else "none"
        raise UsageError(
            f"--frame {args.frame} is out of range: {args.capture} has {records} frames ({last})"
        )
    if fmt == "npz":
        if out.is_dir():
            raise UsageError(f"{out} is a folder; give a file name in it")
        count = write_npz(reader, out, args.frame)
        what = f"{count} frames"
    else:
        count, what = write_per_frame(reader, out, fmt, args.frame)
    if args.frame is not None and count == 0:
        raise UsageError(f"--frame {args.frame}: that record of {args.capture} is damaged")
    note = (
        f", {reader.truncated_bytes} bytes cut short at the end" if reader.truncated_bytes else ""
    )
    print(f"wrote {out} ({what}): {stats_summary(reader.stats)}{note}")
    return 0


def write_npz(reader: CaptureReader, out: Path, only: int | None) -> int:
    n = len(reader) if only is None else 1
    h, w = reader.info.height, reader.info.width
    arrays = {
        "range": np.empty((n, h, w), np.float32),
        "amplitude": np.empty((n, h, w), np.float32),
        "intensity": np.empty((n, h, w), np.float32),
        "valid": np.empty((n, h, w), bool),
        "xyz": np.empty((n, h, w, 3), np.float32),
        "seq": np.empty(n, np.uint32),
        "device_time_us": np.empty(n, np.uint64),
        "host_time_ns": np.empty(n, np.uint64),
    }
    progress = Progress(n, f"converting {reader.path}")
    count = 0
    for index, raw in enumerate(reader.raw_frames()):
        if only is not None and index != only:
            continue
        frame = demodulate(raw, reader.optics, reader.amplitude_threshold)
        i = count
        for name in ("range", "amplitude", "intensity", "valid", "xyz"):
            arrays[name][i] = getattr(frame, name)
        arrays["seq"][i] = frame.sequence
        arrays["device_time_us"][i] = frame.device_time_us
        arrays["host_time_ns"][i] = frame.host_time_ns
        count += 1
        progress.update(count)
    progress.close()
    calib = reader.calibration
    intrinsics = export.intrinsics(calib)
    extra = {
        "K": np.array(intrinsics["camera_info"]["K"]).reshape(3, 3),
        "D": np.array(calib.distortion),
        "distortion_model": np.array("plumb_bob"),
        "distance_offset_m": np.array(calib.distance_offset_m),
        "phase_offset": calib.phase_offset.astype(np.float32),
        "calibration_block": np.frombuffer(reader.capture.calibration_block, np.uint8),
        "intrinsics_json": np.array(json.dumps(intrinsics)),
    }
    np.savez_compressed(
        out, allow_pickle=False, **{k: v[:count] for k, v in arrays.items()}, **extra
    )
    return count


def write_per_frame(
    reader: CaptureReader, out: Path, fmt: str, only: int | None
) -> tuple[int, str]:
    """One file per frame (or the one `only` asks for); returns frames and a summary."""
    single = only is not None and out.suffix.lower() == f".{fmt}" and not out.is_dir()
    folder = out.parent if single else out
    if not single:
        if out.exists() and not out.is_dir():
            raise UsageError(f"{out} is a file: one {fmt} per frame goes into a folder")
        out.mkdir(exist_ok=True)
    writer = export.WRITERS[fmt]
    progress = Progress(len(reader) if only is None else 1, f"converting {reader.path}")
    count = total = 0
    for index, raw in enumerate(reader.raw_frames()):
        if only is not None and index != only:
            continue
        frame = demodulate(raw, reader.optics, reader.amplitude_threshold)
        path = out if single else folder / f"frame-{index:06d}.{fmt}"
        total += writer(path, frame)
        count += 1
        progress.update(count)
    progress.close()
    if fmt == "png":
        export.write_intrinsics(folder / export.INTRINSICS_NAME, reader.calibration)
    unit = "depth pixels" if fmt == "png" else "points"
    return count, f"{count} {fmt} files, {total} {unit}"
