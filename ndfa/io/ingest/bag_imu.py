"""Gravity from a bag's IMU, for world up: what `ndfa ingest bag` records in the recording's meta.

A still accelerometer reads the reaction to gravity: +9.81 m/s^2 along up (ROS REP 145). Per frame,
the readings within `WINDOW_S` of the depth stamp whose magnitude is within `STILL_TOLERANCE` of g
(the sensor not accelerating) are averaged and rotated from the IMU's frame into the camera's
optical frame with the tf between them (on a camera with a built-in IMU, a static transform). A
frame around which the sensor was moving gets no reading. `ndfa detect` turns these per-frame
readings into world up with the frames' poses (`ndfa.trajectory.up_imu.up_from_imu`).

Without a tf between the IMU's frame and the camera's, the readings cannot be put in the camera's
axes: the meta says so and holds none (an IMU's mounting is not guessed).

The meta entry (`meta["imu"]`):
    topic, frame: the Imu topic and its messages' frame_id; messages: how many;
    camera_from_imu: how the readings were rotated ("same frame", "tf IMU -> CAMERA"), or None;
    gravity_camera: [[timestamp_s, x, y, z], ...] per frame with a still reading, m/s^2 in the
        camera's optical frame; timestamp_s is the frame's (Frame.timestamp), to match on;
    note: one line: what was recorded, or why nothing was.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ndfa.core.conventions import STANDARD_GRAVITY
from ndfa.io.ingest.bag_scan import BagScan
from ndfa.io.ingest.tf_buffer import TfLookupError, frame_name

WINDOW_S = 0.05  # readings this close to a frame's stamp count for it (a few at 100-400 Hz)
STILL_TOLERANCE = 0.3  # m/s^2: a reading this close to g in magnitude is taken as still


def imu_meta(scan: BagScan, topic: str, camera: str, frame_stamps: Sequence[int]) -> dict:
    """The meta entry of the IMU topic `topic` for the frames at `frame_stamps` (ns), with the
    readings rotated into `camera` (see the module docstring)."""
    imu_frame = frame_name(scan.imu_frame)
    entry: dict = {"topic": topic, "frame": imu_frame, "messages": len(scan.imu), "camera_from_imu": None,
                   "gravity_camera": []}
    if not scan.imu:
        entry["note"] = f"{topic} has no readable messages"
        return entry
    if imu_frame == camera:
        entry["camera_from_imu"] = "same frame"
    elif not (imu_frame in scan.tf.frames and camera in scan.tf.frames and scan.tf.connects(camera, imu_frame)):
        entry["note"] = (f"no tf between the IMU's frame {imu_frame!r} and the camera's {camera!r}: its readings "
                         "cannot be put in the camera's axes, so they are not used for world up")
        return entry
    else:
        entry["camera_from_imu"] = f"tf {imu_frame} -> {camera}"

    stamps = np.array([stamp for stamp, _ in scan.imu], dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    readings = np.array([acc for _, acc in scan.imu])[order]
    still = np.abs(np.linalg.norm(readings, axis=1) - STANDARD_GRAVITY) <= STILL_TOLERANCE
    window = round(WINDOW_S * 1e9)
    unrotated = 0
    for stamp in frame_stamps:
        lo, hi = np.searchsorted(stamps, [stamp - window, stamp + window + 1])
        near = still[lo:hi]
        if hi == lo or near.mean() < 0.5:  # moving around this frame (or no reading near it)
            continue
        mean = readings[lo:hi][near].mean(axis=0)
        if entry["camera_from_imu"] != "same frame":
            try:
                mean = scan.tf.lookup(camera, imu_frame, int(stamp))[:3, :3] @ mean
            except TfLookupError:
                unrotated += 1
                continue
        entry["gravity_camera"].append([stamp / 1e9, *(float(v) for v in mean)])
    found = len(entry["gravity_camera"])
    entry["note"] = (f"a still reading at {found} of {len(frame_stamps)} frames"
                     + (f" ({unrotated} more without tf at their stamps)" if unrotated else "")
                     + (": the sensor was never still near a frame" if not found else ""))
    return entry
