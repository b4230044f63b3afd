"""Track what moves under an Intel RealSense depth camera with tofcut's tracker, through
pyrealsense2.

    pip install pyrealsense2 tofcut
    python realsense_pyrealsense2.py --seconds 30

librealsense's point cloud (its own lens model, in metres, x right, y down, z forward:
tofcut's camera frame) becomes the frame's points. A D400 camera is a stereo camera, not a
time-of-flight one: it has no amplitude, so none is given and the tracker takes every pixel
as equally noisy. Not run in tofcut's CI, which has no such camera (docs/other-cameras.md).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import pyrealsense2 as rs

import tofcut
from tofcut.driver.intrinsics import Intrinsics


def main() -> None:
    parser = argparse.ArgumentParser(description="Track objects seen by a RealSense camera.")
    parser.add_argument("--seconds", type=float, default=10.0, help="how long to track")
    args = parser.parse_args()

    pipeline = rs.pipeline()
    config = rs.config()
    config.enable_stream(rs.stream.depth, 848, 480, rs.format.z16, 30)
    profile = pipeline.start(config)
    try:
        lens = profile.get_stream(rs.stream.depth).as_video_stream_profile().get_intrinsics()
        intrinsics = Intrinsics(
            width=lens.width,
            height=lens.height,
            fx=lens.fx,
            fy=lens.fy,
            cx=lens.ppx,
            cy=lens.ppy,
        )
        point_cloud = rs.pointcloud()
        tracker = tofcut.Tracker()  # or tofcut.Tracker(belt=...) when the belt is known
        end = time.monotonic() + args.seconds
        while time.monotonic() < end:
            frames = pipeline.wait_for_frames()
            depth = frames.get_depth_frame()
            if not depth:
                continue
            vertices = np.asanyarray(point_cloud.calculate(depth).get_vertices())
            xyz = vertices.view(np.float32).reshape(lens.height, lens.width, 3)
            frame = tofcut.Frame.from_arrays(
                xyz=xyz,  # no depth: (0, 0, 0), left out
                intrinsics=intrinsics,
                time_s=depth.get_timestamp() / 1000.0,  # milliseconds
                sequence=depth.get_frame_number(),
            )
            # the same loop in every example, on purpose: each stands alone, to be copied
            for track in tracker.update(frame).tracks:
                x, y, z = track.centroid
                vx, vy, vz = track.velocity
                print(
                    f"frame {frame.sequence} track {track.id}: at ({x:+.3f}, {y:+.3f}, "
                    f"{z:.3f}) m, moving ({vx:+.2f}, {vy:+.2f}, {vz:+.2f}) m/s"
                )
    finally:
        pipeline.stop()


if __name__ == "__main__":
    main()
