"""Track what moves under an Azure Kinect with tofcut's tracker, through pyk4a.

    pip install pyk4a tofcut     # pyk4a needs Microsoft's Azure Kinect Sensor SDK
    python azure_kinect_pyk4a.py --seconds 30

The depth camera's point cloud (the SDK's own lens model, in millimetres, x right, y down,
z forward: tofcut's camera frame) becomes the frame's points in metres, and its infrared
image, the active brightness, the amplitude the tracker's noise model wants. Not run in
tofcut's CI, which has no such camera (docs/other-cameras.md).
"""

from __future__ import annotations

import argparse
import time

import pyk4a
from pyk4a import CalibrationType, Config, PyK4A

import tofcut
from tofcut.driver.intrinsics import Intrinsics


def main() -> None:
    parser = argparse.ArgumentParser(description="Track objects seen by an Azure Kinect.")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to track")
    args = parser.parse_args()

    k4a = PyK4A(
        Config(
            color_resolution=pyk4a.ColorResolution.OFF,
            depth_mode=pyk4a.DepthMode.NFOV_UNBINNED,  # 640x576
            camera_fps=pyk4a.FPS.FPS_30,
            synchronized_images_only=False,
        )
    )
    k4a.start()
    try:
        k = k4a.calibration.get_camera_matrix(CalibrationType.DEPTH)
        tracker = tofcut.Tracker()  # or tofcut.Tracker(belt=...) when the belt is known
        intrinsics = None
        sequence = 0
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            capture = k4a.get_capture()
            if capture.depth is None or capture.ir is None:
                continue
            if intrinsics is None:
                height, width = capture.depth.shape
                intrinsics = Intrinsics.from_matrix(k, width=width, height=height)
            frame = tofcut.Frame.from_arrays(
                xyz=capture.depth_point_cloud / 1000.0,  # no depth: (0, 0, 0), left out
                amplitude=capture.ir,
                intrinsics=intrinsics,
                time_s=capture.depth_timestamp_usec / 1e6,  # the device's clock
                sequence=sequence,
            )
            sequence += 1
            # the same loop in every example, on purpose: each stands alone, to be copied
            for track in tracker.update(frame).tracks:
                x, y, z = track.centroid
                vx, vy, vz = track.velocity
                print(
                    f"frame {frame.sequence} track {track.id}: at ({x:+.3f}, {y:+.3f}, "
                    f"{z:.3f}) m, moving ({vx:+.2f}, {vy:+.2f}, {vz:+.2f}) m/s"
                )
    finally:
        k4a.stop()


if __name__ == "__main__":
    main()
