"""`tofcut info CAMERA`: a camera's identity, registers and calibration."""

from __future__ import annotations

import argparse
import json
from typing import Any

from tofcut.driver.calibration import Calibration
from tofcut.driver.camera import Camera
from tofcut.driver.protocol import MOD_FREQ_MHZ, Register, unambiguous_range_m
from tofcut.tools.commands.options import add_camera_options, add_source_argument, config_from_args
from tofcut.tools.pipeline.sources import configure, open_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "info",
        help="show a camera's info, registers and calibration",
        epilog=JSON_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_source_argument(p)
    p.add_argument("--json", action="store_true", help="print one JSON object (shape below)")
    add_camera_options(p)
    p.set_defaults(func=run)


JSON_HELP = """\
--json prints one JSON object (fields may be added, never renamed or removed):
  {"source": "emulator", "kind": "camera" or "capture", "serial": "4000002F",
   "firmware": 260, "protocol": 1, "width": 176, "height": 144, "max_fps": 54,
   "configuration": {"mod_freq_mhz": 30.0, "integration_ms": 3.3, "frame_rate_fps": 50.0
                     or null (as fast as it goes), "trigger_mode": "free_run",
                     "unambiguous_range_m": 4.997},
   "registers": {"MOD_FREQ": 1, ...}, "temperature_c": 31.5, "records": null,
   "calibration": {"width": 176, "height": 144, "mod_freq_mhz": 30.0, "fx": 250.0,
                   "fy": 250.0, "cx": 87.6, "cy": 71.3, "distortion_model": "plumb_bob",
                   "D": [k1, k2, p1, p2, k3], "distance_offset_m": 0.0,
                   "phase_offset_rad": {"mean": 0.0, "std": 0.0, "min": 0.0, "max": 0.0}}}
source is the CAMERA as given (a capture's path for a capture). A capture has
configuration and temperature_c null, the registers it was recorded with, and records:
the whole records in the file."""


def calibration_json(calib: Calibration) -> dict[str, Any]:
    """The calibration as `info --json` gives it."""
    offsets = calib.phase_offset
    return {
        "width": calib.width,
        "height": calib.height,
        "mod_freq_mhz": MOD_FREQ_MHZ[calib.mod_code],
        "fx": calib.fx,
        "fy": calib.fy,
        "cx": calib.cx,
        "cy": calib.cy,
        "distortion_model": "plumb_bob",
        "D": list(calib.distortion),
        "distance_offset_m": calib.distance_offset_m,
        "phase_offset_rad": {
            "mean": float(offsets.mean()),
            "std": float(offsets.std()),
            "min": float(offsets.min()),
            "max": float(offsets.max()),
        },
    }


def describe_calibration(calib: Calibration) -> list[str]:
    offsets = calib.phase_offset
    return [
        f"calibration: {calib.width}x{calib.height} at {MOD_FREQ_MHZ[calib.mod_code]:g} MHz",
        f"  fx {calib.fx:.3f}  fy {calib.fy:.3f}  cx {calib.cx:.3f}  cy {calib.cy:.3f}",
        "  k1 {:.5f}  k2 {:.5f}  p1 {:.5f}  p2 {:.5f}  k3 {:.5f}".format(*calib.distortion),
        f"  distance offset {calib.distance_offset_m * 1000:.2f} mm",
        f"  phase offsets: mean {offsets.mean():+.4f} rad, std {offsets.std():.4f}, "
        f"range [{offsets.min():+.4f}, {offsets.max():+.4f}]",
    ]


def run(args: argparse.Namespace) -> int:
    if args.json:
        print(json.dumps(info_json(args), indent=2))
        return 0
    opened = open_source(args.source, seed=args.seed, own_process=False)
    with opened.device as dev:
        info = dev.info
        print(
            f"serial {info.serial_text}  firmware 0x{info.firmware:04x}  protocol {info.protocol}"
        )
        print(f"sensor {info.width}x{info.height}  max {info.max_fps} fps")
        if isinstance(dev, Camera):
            configure(opened, config_from_args(args, dev.config))
            config = dev.config
            print(f"configuration: {config.describe()}")
            print(f"  unambiguous range {unambiguous_range_m(config.mod_freq_code):.3f} m")
            for reg in Register:
                print(f"  {reg.name:<13} 0x{dev.read_register(reg):04x}")
            print(f"  temperature   {dev.temperature_c():.2f} °C")
        else:
            registers = dev.capture.metadata["registers"]
            print(f"capture of {len(dev)} records; registers at start: {registers}")
        for line in describe_calibration(dev.calibration):
            print(line)
    return 0


def info_json(args: argparse.Namespace) -> dict[str, Any]:
    """What `info --json` prints (shape in `JSON_HELP`)."""
    opened = open_source(args.source, seed=args.seed, own_process=False)
    with opened.device as dev:
        info = dev.info
        out: dict[str, Any] = {
            "source": args.source.arg if args.source.kind == "capture" else str(args.source),
            "kind": "camera" if isinstance(dev, Camera) else "capture",
            **info.described(),
            "configuration": None,
            "registers": {},
            "temperature_c": None,
            "records": None,
        }
        if isinstance(dev, Camera):
            configure(opened, config_from_args(args, dev.config))
            config = dev.config
            out["configuration"] = {
                "mod_freq_mhz": config.mod_freq_mhz,
                "integration_ms": round(config.integration_ms, 6),
                "frame_rate_fps": config.frame_rate,
                "trigger_mode": config.trigger_mode.name.lower(),
                "unambiguous_range_m": unambiguous_range_m(config.mod_freq_code),
            }
            out["registers"] = {reg.name: dev.read_register(reg) for reg in Register}
            out["temperature_c"] = round(dev.temperature_c(), 4)
        else:
            out["registers"] = dict(dev.capture.metadata["registers"])
            out["records"] = len(dev)
        out["calibration"] = calibration_json(dev.calibration)
    return out
