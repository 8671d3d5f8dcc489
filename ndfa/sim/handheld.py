"""A hand-held camera's motion: what a person walking through an office with a RealSense does, as
opposed to the smooth robot-like gaze of `ndfa.sim.trajectory`.

Along the route's positions (one per frame at `fps`), the person looks towards the nearest desk
(pitching down towards it: about 20 degrees from a standing eye height), sweeps the view across
the room and back (a pan of +-`pan_deg` about that direction, one sweep every `pan_period_s`), and
the hand shakes (small smoothed rotations and translations every frame) and rolls a little. The
heading and pitch turn at most `max_rate_deg_s` (a quick pan: 90 deg/s, 3 deg per frame at 30 Hz),
which is what odometry then has to follow. The person walks at a pace that drifts slowly about
the route's mean step (`walking_arc_lengths`: slowing down and speeding up by `pace_variation`),
not at a machine's constant speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import SimError
from ndfa.core.geometry import axis_angle_to_matrix, make_pose

MOTIONS = ("smooth", "handheld")


@dataclass(frozen=True)
class HandheldMotion:
    """Settings of `handheld_poses`: angles in degrees, times in seconds, lengths in metres."""

    max_rate_deg_s: float = 90.0    # the fastest turn of heading (pitch: a third of it)
    pan_deg: float = 35.0           # the sweep's amplitude about the direction of the nearest desk
    pan_period_s: float = 5.0       # one sweep across and back
    max_down_deg: float = 35.0      # the camera looks at most this far below the horizon
    roll_deg: float = 2.0           # slow roll of the hand (standard deviation)
    shake_deg: float = 0.3          # tremor: rotation per frame (standard deviation, smoothed)
    shake_m: float = 0.002          # tremor: translation (standard deviation, smoothed)
    smoothing_s: float = 0.1        # the tremor's correlation time
    pace_variation: float = 0.2     # the walking pace's standard deviation, a fraction of the mean (capped at 2x)
    pace_time_s: float = 2.0        # how long a faster or slower stretch lasts (the pace's correlation time)

    def __post_init__(self) -> None:
        if not (self.max_rate_deg_s > 0 and self.pan_period_s > 0 and self.smoothing_s > 0):
            raise SimError(f"hand-held motion needs positive rates and times: {self}")
        if not (0.0 <= self.pace_variation < 0.5 and self.pace_time_s > 0):
            raise SimError(f"hand-held motion needs pace_variation in [0, 0.5) and pace_time_s > 0: {self}")
        if min(self.pan_deg, self.roll_deg, self.shake_deg, self.shake_m) < 0 or not 0 < self.max_down_deg < 90:
            raise SimError(f"hand-held motion amplitudes must be >= 0 and max_down_deg in (0, 90): {self}")


def handheld_poses(eyes: np.ndarray, targets: np.ndarray, fps: float, motion: HandheldMotion,
                   rng: np.random.Generator) -> np.ndarray:
    """Camera-to-world poses (N, 4, 4) of a hand-held camera at `eyes` (N, 3) that looks towards
    `targets` (N, 3) (the nearest desk), sweeping and shaking as `motion` says (see the module
    docstring). World z is up."""
    eyes, targets = np.asarray(eyes, dtype=float), np.asarray(targets, dtype=float)
    n = len(eyes)
    times = np.arange(n) / fps
    gaze = targets - eyes
    base_heading = np.unwrap(np.arctan2(gaze[:, 1], gaze[:, 0]))
    base_pitch = np.arctan2(gaze[:, 2], np.linalg.norm(gaze[:, :2], axis=1))
    phase = rng.uniform(0.0, 2.0 * np.pi)
    pan = np.radians(motion.pan_deg) * np.sin(2.0 * np.pi * times / motion.pan_period_s + phase)
    smooth = max(motion.smoothing_s * fps, 1e-6)
    tremor = _smoothed_noise(rng, (n, 3), smooth) * np.radians(motion.shake_deg)
    wanted_heading = base_heading + pan + tremor[:, 0]
    wanted_pitch = np.maximum(base_pitch, -np.radians(motion.max_down_deg)) + tremor[:, 1]
    step = np.radians(motion.max_rate_deg_s) / fps
    # Pitch turns at a third of the rate: a person tilts the camera slowly and pans it fast, and
    # together they stay near max_rate_deg_s.
    heading, pitch = _rate_limited(wanted_heading, step), _rate_limited(wanted_pitch, step / 3.0)
    roll = _smoothed_noise(rng, (n, 1), fps)[:, 0] * np.radians(motion.roll_deg) + tremor[:, 2]
    shaken = eyes + _smoothed_noise(rng, (n, 3), smooth) * motion.shake_m
    return np.stack([_pose(e, h, p, r) for e, h, p, r in zip(shaken, heading, pitch, roll)])


def walking_arc_lengths(length_m: float, mean_step_m: float, fps: float, motion: HandheldMotion,
                        rng: np.random.Generator) -> np.ndarray:
    """Distances along a route of `length_m` at which the frames are taken: `mean_step_m` per frame
    on average, the pace drifting by `motion.pace_variation` (standard deviation, capped at twice
    that) over stretches of `motion.pace_time_s`; starts at 0, stays below `length_m`."""
    most = int(np.ceil(length_m / (mean_step_m * (1.0 - 2.0 * motion.pace_variation)))) + 1
    drift = _smoothed_noise(rng, (most, 1), motion.pace_time_s * fps)[:, 0] if most > 1 else np.zeros(most)
    pace = 1.0 + motion.pace_variation * np.clip(drift, -2.0, 2.0)
    arc = np.r_[0.0, np.cumsum(mean_step_m * pace[:-1])]
    return arc[arc < length_m]


def angular_speeds_deg_s(poses: np.ndarray, fps: float) -> np.ndarray:
    """The rotation between consecutive poses (N - 1,), in degrees per second."""
    relative = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    cos = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos)) * fps


def _rate_limited(values: np.ndarray, step: float) -> np.ndarray:
    """`values` followed with at most `step` change per sample."""
    out = np.empty_like(values)
    out[0] = values[0]
    for i in range(1, len(values)):
        out[i] = out[i - 1] + np.clip(values[i] - out[i - 1], -step, step)
    return out


def _smoothed_noise(rng: np.random.Generator, shape: tuple[int, int], sigma_samples: float) -> np.ndarray:
    """Gaussian noise smoothed along axis 0 by a Gaussian of `sigma_samples`, rescaled to unit
    standard deviation."""
    noise = rng.normal(size=shape)
    radius = int(np.ceil(3 * sigma_samples))
    if radius >= 1:
        kernel = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma_samples) ** 2)
        padded = np.pad(noise, ((radius, radius), (0, 0)), mode="reflect" if shape[0] > radius else "edge")
        noise = np.stack([np.convolve(padded[:, d], kernel / kernel.sum(), mode="valid") for d in range(shape[1])], axis=1)
    return noise / max(float(noise.std()), 1e-12)


def _pose(eye: np.ndarray, heading: float, pitch: float, roll: float) -> np.ndarray:
    """An OpenCV camera at `eye` looking at `heading` (about z from x) and `pitch` (up from the
    horizon), rolled by `roll` about its optical axis."""
    forward = np.array([np.cos(pitch) * np.cos(heading), np.cos(pitch) * np.sin(heading), np.sin(pitch)])
    right = np.array([np.sin(heading), -np.cos(heading), 0.0])
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward], axis=1) @ axis_angle_to_matrix(np.array([0.0, 0.0, roll]))
    return make_pose(rotation, eye)
