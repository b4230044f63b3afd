"""`tofcut devices`: list the cameras on the bus."""

from __future__ import annotations

import argparse
import json
from typing import Any

from tofcut.driver.camera import Camera, list_cameras
from tofcut.driver.errors import DeviceError
from tofcut.driver.protocol import PRODUCT_ID, VENDOR_ID
from tofcut.sim.device import EmulatedCamera
from tofcut.sim.usb_backend import EmulatedBackend
from tofcut.tools.pipeline.sources import scene_source


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "devices",
        help="list cameras (serial, firmware, resolution)",
        description="List the cameras on the bus (and with --emulator an emulated one).",
        epilog=JSON_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--emulator", action="store_true", help="also list an emulated camera")
    p.add_argument("--json", action="store_true", help="print one JSON object (shape below)")
    p.add_argument("--vid", type=lambda s: int(s, 16), default=VENDOR_ID, help="USB vendor id, hex")
    p.add_argument(
        "--pid", type=lambda s: int(s, 16), default=PRODUCT_ID, help="USB product id, hex"
    )
    p.set_defaults(func=run)


JSON_HELP = """\
--json prints one JSON object (fields may be added, never renamed or removed):
  {"cameras": [{"source": "usb:1A2B3C4D", "bus": "usb" or "emulator", "serial": "1A2B3C4D",
                "firmware": "1.02", "firmware_code": 258, "width": 176, "height": 144,
                "usb_bus": 1, "usb_address": 4, "error": null}, ...],
   "errors": [{"bus": "usb", "error": "..."}, ...]}
source is what other commands take as CAMERA (usb:SERIAL, or emulator); serial, width,
height, usb_bus and usb_address are null when the camera could not be asked (error then
says why); errors lists the buses that could not be searched."""


def run(args: argparse.Namespace) -> int:
    cameras, errors = find(args)
    if args.json:
        print(json.dumps({"cameras": cameras, "errors": errors}, indent=2))
        return 0
    for error in errors:
        print(f"{error['bus']}: {error['error']}")
    if not cameras:
        print("no cameras found (try --emulator for an emulated one)")
    for cam in cameras:
        size = f"{cam['width']}x{cam['height']}" if cam["error"] is None else f"({cam['error']})"
        print(
            f"{cam['bus']}:{cam['serial'] or '?'}  firmware {cam['firmware']}  {size}"
            f"  bus {cam['usb_bus']} address {cam['usb_address']}"
        )
    return 0


def find(args: argparse.Namespace) -> tuple[list[dict[str, Any]], list[dict[str, str]]]:
    """The cameras found (as `--json` gives them) and the buses that could not be searched."""
    buses: list[tuple[str, object]] = [("usb", None)]
    if args.emulator:
        buses.append(("emulator", EmulatedBackend([EmulatedCamera(scene_source(None))])))
    cameras: list[dict[str, Any]] = []
    errors: list[dict[str, str]] = []
    for name, backend in buses:
        try:
            found = list_cameras(backend=backend, vendor_id=args.vid, product_id=args.pid)
        except DeviceError as exc:
            errors.append({"bus": name, "error": str(exc)})
            continue
        for ids in found:
            size: tuple[int, int] | None = None
            error = None
            try:
                with Camera.open(
                    ids.serial, backend=backend, vendor_id=args.vid, product_id=args.pid
                ) as cam:
                    size = (cam.info.width, cam.info.height)
            except DeviceError as exc:
                error = str(exc)
            cameras.append(
                {
                    "source": f"usb:{ids.serial}" if name == "usb" and ids.serial else name,
                    "bus": name,
                    "serial": ids.serial,
                    "firmware": f"{ids.firmware >> 8:x}.{ids.firmware & 0xFF:02x}",
                    "firmware_code": ids.firmware,
                    "width": None if size is None else size[0],
                    "height": None if size is None else size[1],
                    "usb_bus": ids.bus,
                    "usb_address": ids.address,
                    "error": error,
                }
            )
    return cameras, errors
