"""Picture of rerun's web viewer showing a recording: `make_picture.py RUN.rrd [-o viewer.png]`.

Serves the recording with the rerun CLI that comes with rerun-sdk (`rerun --serve-web`), opens
the web viewer in headless Chromium (software WebGL, SwiftShader) driven through chromedriver's
WebDriver HTTP API, waits until the picture stops changing, and saves a screenshot. Everything
stays on loopback. Needs the Debian packages `chromium` and `chromium-driver`.

    scripts/uv run python docs/viewer/make_picture.py run.rrd
"""

from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import rerun_cli

HERE = Path(__file__).resolve().parent
CHROMIUM_FLAGS = [
    "--headless=new",
    "--no-sandbox",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--force-device-scale-factor=1",
    "--hide-scrollbars",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    # Nothing leaves the machine: every host name but loopback fails to resolve.
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_port(port: int, proc: subprocess.Popen[bytes], timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise SystemExit(f"{proc.args[0]} exited with {proc.returncode}")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.5):
                return
        except OSError:
            time.sleep(0.2)
    raise SystemExit(f"nothing listens on port {port} after {timeout_s} s")


class WebDriver:
    """The few WebDriver (W3C) calls needed, over plain HTTP to chromedriver."""

    def __init__(self, port: int) -> None:
        self.base = f"http://127.0.0.1:{port}"
        self.session = ""

    def call(self, method: str, path: str, body: object | None = None) -> object:
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(
            self.base + path, data=data, method=method, headers={"Content-Type": "application/json"}
        )
        with urllib.request.urlopen(req, timeout=120) as reply:
            return json.load(reply)["value"]

    def start(self, width: int, height: int) -> None:
        options = {
            "binary": shutil.which("chromium") or "chromium",
            "args": [*CHROMIUM_FLAGS, f"--window-size={width},{height}"],
        }
        caps = {"capabilities": {"alwaysMatch": {"goog:chromeOptions": options}}}
        reply = self.call("POST", "/session", caps)
        assert isinstance(reply, dict)
        self.session = str(reply["sessionId"])

    def do(self, method: str, path: str, body: object | None = None) -> object:
        return self.call(method, f"/session/{self.session}{path}", body)

    def screenshot(self) -> bytes:
        return base64.b64decode(str(self.do("GET", "/screenshot")))


def png_size(png: bytes) -> tuple[int, int]:
    width, height = struct.unpack(">II", png[16:24])
    return int(width), int(height)


def picture(
    rrd: Path,
    out: Path,
    width: int,
    height: int,
    settle_s: float,
    timeout_s: float,
) -> tuple[int, int]:
    """Serve `rrd`, screenshot the web viewer once it is still, write `out`; its size."""
    web, grpc, driver_port = free_port(), free_port(), free_port()
    env = dict(os.environ, RERUN_ANALYTICS="0")
    rerun_bin = Path(rerun_cli.__file__).with_name("rerun")
    server = subprocess.Popen(
        [
            str(rerun_bin),
            "--serve-web",
            str(rrd),
            "--bind",
            "127.0.0.1",
            "--web-viewer-port",
            str(web),
            "--port",
            str(grpc),
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    chromedriver = shutil.which("chromedriver") or "chromedriver"
    driver_proc = subprocess.Popen(
        [chromedriver, f"--port={driver_port}"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    driver = WebDriver(driver_port)
    try:
        wait_for_port(web, server, 30)
        wait_for_port(driver_port, driver_proc, 30)
        driver.start(width, height)
        # Headless Chromium counts its (invisible) window frame: grow it to the asked viewport.
        shot_w, shot_h = png_size(driver.screenshot())
        driver.do(
            "POST", "/window/rect", {"width": 2 * width - shot_w, "height": 2 * height - shot_h}
        )
        proxy = urllib.parse.quote(f"rerun+http://127.0.0.1:{grpc}/proxy", safe="")
        driver.do("POST", "/url", {"url": f"http://127.0.0.1:{web}/?url={proxy}"})
        start = time.monotonic()
        previous = b""
        while True:
            time.sleep(settle_s)
            shot = driver.screenshot()
            if shot == previous and time.monotonic() - start > 3 * settle_s:
                break
            if time.monotonic() - start > timeout_s:
                raise SystemExit(f"the viewer did not settle within {timeout_s} s")
            previous = shot
        out.write_bytes(shot)
        return png_size(shot)
    finally:
        if driver.session:
            driver.do("DELETE", "")
        for proc in (driver_proc, server):
            proc.terminate()
            proc.wait(10)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rrd", type=Path, help="the recording to show")
    parser.add_argument("-o", "--out", type=Path, default=HERE / "viewer.png")
    parser.add_argument("--size", default="1600x900", help="viewport, WIDTHxHEIGHT")
    parser.add_argument(
        "--settle",
        type=float,
        default=3.0,
        help="seconds between screenshots that must match (default 3)",
    )
    parser.add_argument("--timeout", type=float, default=180.0)
    args = parser.parse_args()
    if not args.rrd.is_file():
        parser.error(f"{args.rrd} is not a file")
    width, height = (int(x) for x in args.size.split("x"))
    w, h = picture(args.rrd, args.out, width, height, args.settle, args.timeout)
    print(f"wrote {args.out} ({w}x{h})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
