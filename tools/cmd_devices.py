"""`tofcut devices`: list the cameras on the bus."""

from __future__ import annotations

import argparse

from tofcut.driver.camera import Camera, list_cameras
from tofcut.driver.errors import DeviceError
from tofcut.driver.protocol import PRODUCT_ID, VENDOR_ID
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.usb_backend import EmulatedBackend
from tofcut.tools.sources import scene_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("devices", help="list cameras (serial, firmware, resolution)")
    p.add_argument("--emulator", action="store_true", help="also list an emulated camera")
    p.add_argument("--vid", type=lambda s: int(s, 16), default=VENDOR_ID, help="USB vendor id, hex")
    p.add_argument(
        "--pid", type=lambda s: int(s, 16), default=PRODUCT_ID, help="USB product id, hex"
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    buses: list[tuple[str, object]] = [("usb", None)]
    if args.emulator:
        buses.append(("emulator", EmulatedBackend([EmulatedCamera(scene_source(None))])))
    rows = []
    for name, backend in buses:
        try:
            found = list_cameras(backend=backend, vendor_id=args.vid, product_id=args.pid)
        except DeviceError as exc:
            print(f"{name}: {exc}")
            continue
        for ids in found:
            resolution = "?"
            try:
                with Camera.open(
                    ids.serial, backend=backend, vendor_id=args.vid, product_id=args.pid
                ) as cam:
                    resolution = f"{cam.info.width}x{cam.info.height}"
            except DeviceError as exc:
                resolution = f"({exc})"
            firmware = f"{ids.firmware >> 8:x}.{ids.firmware & 0xFF:02x}"
            rows.append(
                f"{name}:{ids.serial or '?'}  firmware {firmware}  {resolution}"
                f"  bus {ids.bus} address {ids.address}"
            )
    if not rows:
        print("no cameras found (try --emulator for an emulated one)")
    for row in rows:
        print(row)
    return 0
