"""`tofcut ports`: list the serial ports a conveyor controller could be on."""

from __future__ import annotations

import argparse

from serial.tools import list_ports


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("ports", help="list serial ports (for --conveyor PORT)")
    p.add_argument(
        "--links",
        action="store_true",
        help="also list symlinks to ports (e.g. /dev/serial/by-id/..., stable across replugs)",
    )
    p.set_defaults(func=run)


def describe_port(port: list_ports.ListPortInfo) -> str:
    """One line: device, then what the system knows about it (USB ids, serial, maker)."""
    parts = [port.device]
    if port.vid is not None and port.pid is not None:
        parts.append(f"usb {port.vid:04x}:{port.pid:04x}")
    if port.serial_number:
        parts.append(f"serial {port.serial_number}")
    if port.description and port.description != "n/a":
        parts.append(port.description)
    if port.manufacturer:
        parts.append(port.manufacturer)
    return "  ".join(parts)


def run(args: argparse.Namespace) -> int:
    ports = sorted(list_ports.comports(include_links=args.links), key=lambda p: p.device)
    if not ports:
        print("no serial ports found")
    for port in ports:
        print(describe_port(port))
    return 0
