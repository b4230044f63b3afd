"""`tofcut convert CAPTURE -o frames.npz`: demodulated arrays for analysis."""

from __future__ import annotations

import argparse

import numpy as np

from tofcut.driver.capture import CaptureReader
from tofcut.tools.arguments import capture_file, output_file
from tofcut.tools.cmd_record import stats_summary
from tofcut.tools.progress import Progress


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "convert",
        help="capture → npz of range, amplitude, intensity, valid, xyz and timestamps",
    )
    p.add_argument("capture", type=capture_file, metavar="CAPTURE")
    p.add_argument("-o", "--output", type=output_file, required=True, metavar="FILE.npz")
    p.add_argument("--amplitude-threshold", type=float, default=0.0, metavar="COUNTS")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    reader = CaptureReader(args.capture, amplitude_threshold=args.amplitude_threshold)
    n, h, w = len(reader), reader.info.height, reader.info.width
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
    progress = Progress(n, f"converting {args.capture}")
    count = 0
    for frame in reader.frames():
        i = count
        for name in ("range", "amplitude", "intensity", "valid", "xyz"):
            arrays[name][i] = getattr(frame, name)
        arrays["seq"][i] = frame.sequence
        arrays["device_time_us"][i] = frame.device_time_us
        arrays["host_time_ns"][i] = frame.host_time_ns
        count += 1
        progress.update(count)
    progress.close()
    np.savez_compressed(
        args.output, allow_pickle=False, **{k: v[:count] for k, v in arrays.items()}
    )
    note = (
        f", {reader.truncated_bytes} bytes cut short at the end" if reader.truncated_bytes else ""
    )
    print(f"wrote {args.output}: {stats_summary(reader.stats)}{note}")
    return 0
