"""`tofcut info CAMERA`: a camera's identity, registers and calibration."""

from __future__ import annotations

import argparse

from tofcut.driver.calibration import Calibration
from tofcut.driver.camera import Camera
from tofcut.driver.protocol import MOD_FREQ_MHZ, Register, unambiguous_range_m
from tofcut.tools.options import add_camera_options, add_source_argument, config_from_args
from tofcut.tools.sources import open_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("info", help="show a camera's info, registers and calibration")
    add_source_argument(p)
    add_camera_options(p)
    p.set_defaults(func=run)


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
    opened = open_source(args.source, seed=args.seed)
    with opened.device as dev:
        info = dev.info
        print(
            f"serial {info.serial_text}  firmware 0x{info.firmware:04x}  protocol {info.protocol}"
        )
        print(f"sensor {info.width}x{info.height}  max {info.max_fps} fps")
        if isinstance(dev, Camera):
            asked = config_from_args(args, dev.config)
            if asked is not None:
                dev.configure(asked)
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
