"""World up from an IMU: the accelerometer of a still sensor reads +g along up (ROS REP 145,
sensor_msgs/Imu). `ndfa ingest bag` records per-frame still readings in the camera's axes
(ndfa.io.ingest.bag_imu); `ndfa detect` turns them into world up with the frames' poses
(`up_from_imu`), and `ndfa.trajectory.up`'s plane estimate checks it (ndfa.run.world).
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np

from ndfa.core.conventions import STANDARD_GRAVITY, world_up
from ndfa.core.errors import TrajectoryError
from ndfa.trajectory.up import UpEstimate, angle_deg


def up_from_accelerations(acc_camera: np.ndarray, poses: np.ndarray, still_tolerance: float = 0.3,
                          agree_deg: float = 5.0, min_samples: int = 10) -> UpEstimate:
    """World up from accelerometer readings of a (mostly) still sensor.

    A still accelerometer measures the reaction to gravity: +9.81 m/s^2 along up (ROS REP 145,
    sensor_msgs/Imu). Each sample whose magnitude is within still_tolerance (m/s^2) of standard
    gravity counts as still; its direction, rotated into the world with the camera's pose at that
    time, is one vote for up, and up is their mean.

    acc_camera: (N, 3) linear accelerations in m/s^2, expressed in the camera's (OpenCV) frame: the
        caller applies the IMU-to-camera rotation and interpolates the poses to the IMU's times.
    poses: (N, 4, 4) (or (N, 3, 3) rotations) camera-to-world at the samples' times.
    agree_deg: a still sample agrees when its up is within this angle of the mean; most must.
    min_samples: fewer still samples than this give no estimate.
    """
    started = time.perf_counter()
    acc = np.asarray(acc_camera, dtype=np.float64).reshape(-1, 3)
    rotations = np.asarray(poses, dtype=np.float64)[..., :3, :3].reshape(-1, 3, 3)
    if len(acc) != len(rotations):
        raise TrajectoryError(f"up from accelerations needs one pose per sample, got {len(acc)} samples and {len(rotations)} poses")
    n = len(acc)
    magnitude = np.linalg.norm(acc, axis=1)
    still = np.isfinite(magnitude) & (np.abs(magnitude - STANDARD_GRAVITY) <= still_tolerance)
    n_still = int(still.sum())
    fraction = n_still / n if n else 0.0
    if n_still < min_samples:
        return UpEstimate(False, f"{n_still} of {n} accelerometer samples are still (|a| within {still_tolerance:g} m/s^2 "
                          f"of g; need {min_samples})", None, "imu", n, n_still, 0, fraction, float("nan"),
                          time.perf_counter() - started)
    ups = np.einsum("nij,nj->ni", rotations[still], acc[still] / magnitude[still, None])
    up = ups.mean(axis=0)
    up /= np.linalg.norm(up)
    angles = np.degrees(np.arccos(np.clip(ups @ up, -1.0, 1.0)))
    agreeing = int((angles <= agree_deg).sum())
    spread = float(np.sqrt(np.mean(angles**2)))
    seconds = time.perf_counter() - started
    if agreeing < 0.5 * n_still:
        return UpEstimate(False, f"still accelerometer samples disagree: {agreeing} of {n_still} within {agree_deg:g} deg "
                          f"(spread {spread:.1f} deg): poses or IMU-to-camera rotation wrong?", None, "imu", n, n_still,
                          agreeing, fraction, spread, seconds)
    reason = (f"up from {n_still} still accelerometer samples: {agreeing} agree (spread {spread:.1f} deg), "
              f"{angle_deg(up, world_up()):.1f} deg from the world's z")
    return UpEstimate(True, reason, up, "imu", n, n_still, agreeing, fraction, spread, seconds, "high", "",
                      spread / np.sqrt(n_still))


def imu_gravity(meta: dict) -> dict[float, np.ndarray]:
    """A recording's still accelerometer readings by frame timestamp: {Frame.timestamp: (3,) m/s^2 in
    the camera's optical frame}, from meta["imu"]["gravity_camera"] as `ndfa ingest bag` records it
    (ndfa.io.ingest.bag_imu); empty when the recording has none."""
    imu = meta.get("imu")
    rows = imu.get("gravity_camera") if isinstance(imu, dict) else None
    if not isinstance(rows, list):
        return {}
    gravity = {}
    for row in rows:
        if isinstance(row, list) and len(row) == 4 and all(isinstance(v, (int, float)) for v in row):
            gravity[float(row[0])] = np.array(row[1:], dtype=np.float64)
    return gravity


def up_from_imu(gravity: dict[float, np.ndarray], frames: Iterable[tuple[float, np.ndarray]],
                max_dt_s: float = 1e-6, min_samples: int = 3, agree_deg: float = 5.0) -> UpEstimate:
    """World up from per-frame accelerometer readings (`imu_gravity`) and the frames' poses: each
    frame (timestamp, (4, 4) camera-to-world pose) with a reading within `max_dt_s` of its timestamp
    is one sample of `up_from_accelerations`. Fewer than `min_samples` such frames give no estimate."""
    times = np.array(sorted(gravity), dtype=np.float64)
    acc, poses, looked = [], [], 0
    for timestamp, pose in frames:
        looked += 1
        if not len(times):
            continue
        nearest = times[np.argmin(np.abs(times - timestamp))]
        if abs(nearest - timestamp) <= max_dt_s:
            acc.append(gravity[float(nearest)])
            poses.append(pose)
    if len(acc) < min_samples:
        return UpEstimate(False, f"an IMU reading at {len(acc)} of the {looked} frames looked at (need {min_samples})",
                          None, "imu", looked, len(acc), 0, 0.0, float("nan"))
    return up_from_accelerations(np.array(acc), np.array(poses), agree_deg=agree_deg, min_samples=min_samples)
