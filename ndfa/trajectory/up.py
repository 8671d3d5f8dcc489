"""World up from the data: the direction of gravity in a session's world frame, and the rotation
that levels the world so that the z-up core (core/conventions.py) can use its poses unchanged.

Why it is needed: with estimated poses the world is the first camera's frame (up is roughly that
camera's -y), and datasets use their own world frames. In such a world the segmentation finds no
horizontal support plane, the object trees cut the wrong axes and the NDF's up cue points sideways.

How (`estimate_up`): man-made scenes have large horizontal planes (floor, table tops, shelves)
whose normals all point up, while walls and cabinet fronts point sideways. Per frame, the depth
image is cut into small patches; the patches that are planar give one normal each, oriented
towards the camera and rotated into the world with the frame's pose. The normals of all frames
(each frame weighing the same) are voted into direction bins on the sphere. Up is the strongest
cluster among the directions not far from the cameras' mean -y axis (people and robots hold
cameras roughly upright: walls lie about 90 degrees from it, the floor within the camera's pitch),
refined as the mean of its inlier normals. The estimate is checked frame by frame: each frame that
sees a horizontal plane gives its own up, and the frames must agree with the estimate. When there
is no horizontal plane, or the frames disagree (wrong poses), the estimate says so in one line
(`ok=False`, `reason`) instead of guessing.

A recording with an IMU has a cheaper prior: the accelerometer of a still sensor reads +g along up
(`up_from_accelerations`).

No file I/O here: callers pass frames (e.g. `RecordingReader.frames(step=...)`) or arrays.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from ndfa.core.conventions import STANDARD_GRAVITY, depth_in_range, world_up
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import backproject
from ndfa.trajectory.level import levelling_rotation

# The cameras' mean -y axis (the prior for up) must be at least this long: for upright cameras it
# is about the cosine of their mean pitch; for cameras (or poses) pointing every way, about 1/sqrt(n).
MIN_UPRIGHT = 0.2


@dataclass(frozen=True)
class UpConfig:
    """Settings of `estimate_up` (defaults checked on the 7-Scenes redkitchen slice and the
    simulator's scenes: docs/world_up.md).

    pixel_stride: the depth image is sampled every `pixel_stride` pixels in both directions; normals
        need far fewer points than the image has.
    patch_size: a patch is `patch_size` x `patch_size` samples (20 x 20 pixels at the defaults, about
        7 cm at 2 m for a 585 px focal length): large enough to average the depth noise, small
        enough to fit on a table top.
    max_patch_rms_m, patch_rms_per_m2: a patch is planar when the RMS distance of its points to
        their best-fit plane is below max_patch_rms_m + patch_rms_per_m2 * z^2 (z: its depth in
        metres), because the noise of a triangulating depth camera grows with z^2. Depth edges and
        curved surfaces (mugs, chair legs) fail it.
    max_patches_per_frame: planar patches kept per frame (evenly sampled), for speed.
    min_patches_per_frame: a frame with fewer planar patches gives no normals (nearly no depth).
    bins: number of direction bins on the sphere (a Fibonacci lattice: ~4.5 degrees apart at 2000).
    cluster_deg: radius of a cluster: a bin's strength is the weight of the normals within it.
    prior_cone_deg: up is searched within this angle of the cameras' mean -y axis (or of `prior_up`).
        Walls are ~90 degrees from -y for an upright camera; the floor is at the camera's mean
        pitch, so cameras pitched down more than this on average are not supported.
    inlier_deg: the normals within this angle of up are its inliers (refinement, support, frames).
    min_support_fraction: the up cluster must hold at least this fraction of all planar normals
        (each frame weighing the same), or the scene has no horizontal plane.
    frame_min_patches: a frame sees a horizontal plane when its strongest cluster within the cone
        holds at least this many of its normals; its own up is that cluster refined (as the
        estimate, but from the frame's normals alone).
    agree_deg: a frame agrees when its own up is within this angle of the estimate.
    min_agreeing_frames, min_agreeing_fraction: the estimate stands when at least this many frames,
        and this fraction of the frames that see a horizontal plane, agree.
    """

    pixel_stride: int = 4
    patch_size: int = 5
    max_patch_rms_m: float = 0.002
    patch_rms_per_m2: float = 0.001
    max_patches_per_frame: int = 3000
    min_patches_per_frame: int = 20
    bins: int = 2000
    cluster_deg: float = 10.0
    prior_cone_deg: float = 60.0
    inlier_deg: float = 10.0
    min_support_fraction: float = 0.05
    frame_min_patches: int = 10
    agree_deg: float = 5.0
    min_agreeing_frames: int = 3
    min_agreeing_fraction: float = 0.6

    def __post_init__(self) -> None:
        for name in ("pixel_stride", "bins", "max_patches_per_frame", "min_patches_per_frame",
                     "frame_min_patches", "min_agreeing_frames"):
            if not getattr(self, name) >= 1:
                raise TrajectoryError(f"up estimate {name} must be >= 1, got {getattr(self, name)}")
        if self.patch_size < 3:
            raise TrajectoryError(f"up estimate patch_size must be >= 3 (a plane needs 3 points), got {self.patch_size}")
        for name in ("cluster_deg", "prior_cone_deg", "inlier_deg", "agree_deg"):
            if not 0.0 < getattr(self, name) < 180.0:
                raise TrajectoryError(f"up estimate {name} must be in (0, 180) degrees, got {getattr(self, name)}")
        for name in ("min_support_fraction", "min_agreeing_fraction"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise TrajectoryError(f"up estimate {name} must be in [0, 1], got {getattr(self, name)}")
        if self.max_patch_rms_m < 0.0 or self.patch_rms_per_m2 < 0.0:
            raise TrajectoryError("up estimate max_patch_rms_m and patch_rms_per_m2 must be >= 0")


@dataclass(frozen=True)
class UpEstimate:
    """World up of a session, and how it was found.

    ok: whether up was found; when False, `up_world` is None and `reason` says why in one line.
    reason: one line: what was found (ok) or what was missing.
    up_world: unit 3-vector, the world's up (minus gravity) in the session's world frame, or None.
    method: "planes" (normals of horizontal planes, `estimate_up`) or "imu" (`up_from_accelerations`).
    frames: frames (or IMU samples) given.
    frames_used: frames with enough planar patches (IMU: still samples).
    frames_agreeing: frames whose own horizontal plane (IMU: sample) is within agree_deg of up.
    support_fraction: fraction of all planar normals (each frame weighing the same) within
        inlier_deg of up (IMU: fraction of the samples that are still). 0 when not found.
    spread_deg: RMS angle between the frames' own ups (IMU: the still samples) and up; nan when
        there are none.
    seconds: time the estimate took.
    """

    ok: bool
    reason: str
    up_world: np.ndarray | None
    method: str
    frames: int
    frames_used: int
    frames_agreeing: int
    support_fraction: float
    spread_deg: float
    seconds: float = 0.0

    @property
    def tilt_deg(self) -> float:
        """Angle between up and the world's z axis in degrees (0: the world is already z-up); nan
        when up was not found."""
        if self.up_world is None:
            return float("nan")
        return angle_deg(self.up_world, world_up())

    def levelling(self) -> np.ndarray:
        """The (3, 3) rotation that levels the world (see `levelling_rotation`); raises
        TrajectoryError with the reason when up was not found."""
        if self.up_world is None:
            raise TrajectoryError(f"no world up to level with: {self.reason}")
        return levelling_rotation(self.up_world)

    def to_dict(self) -> dict:
        """Plain values, for provenance in a recording's meta or a report."""
        values = dataclasses.asdict(self)
        values["up_world"] = None if self.up_world is None else [float(x) for x in self.up_world]
        values["tilt_deg"] = self.tilt_deg
        return values


# -- estimate from planes ---------------------------------------------------------------------


def estimate_up(frames: Iterable[Frame], config: UpConfig = UpConfig(), prior_up: np.ndarray | None = None) -> UpEstimate:
    """World up from the normals of the horizontal planes the frames see (see the module docstring).

    frames: the session's frames (depth in metres, K, camera-to-world poses). Every frame given is
        used, one at a time (only its normals are kept), so pass a subset for speed, e.g.
        `reader.frames(stop=50)` or `reader.frames(step=len(reader) // 50)`: 50 frames are plenty
        when they see the floor or a table.
    prior_up: where to search for up instead of the cameras' mean -y axis (e.g. an IMU's estimate,
        or the world's z for a world believed to be roughly z-up).
    """
    started = time.perf_counter()
    normals: list[np.ndarray] = []  # per frame with planar patches: world normals (n, 3)
    camera_down_sum = np.zeros(3)
    n_frames = 0
    for frame in frames:
        n_frames += 1
        rotation = frame.pose_world_camera[:3, :3]
        camera_down_sum += rotation[:, 1]
        frame_normals = planar_normals(frame.depth, frame.K, config)
        if len(frame_normals) >= config.min_patches_per_frame:
            normals.append(frame_normals @ rotation.T)

    def failed(reason: str, support: float = 0.0, agreeing: int = 0, spread: float = float("nan")) -> UpEstimate:
        return UpEstimate(False, reason, None, "planes", n_frames, len(normals), agreeing, support, spread,
                          time.perf_counter() - started)

    if n_frames == 0:
        return failed("no frames given")
    if not normals:
        return failed(f"no planar surfaces in any of {n_frames} frames (no depth in range, or too little of it)")

    if prior_up is None:
        prior = -camera_down_sum / n_frames
        if np.linalg.norm(prior) < MIN_UPRIGHT:
            return failed(f"the cameras' -y axes point every way (mean length {np.linalg.norm(prior):.2f} < {MIN_UPRIGHT:g} "
                          f"over {n_frames} frames): cameras not upright or poses wrong; no prior for up")
    else:
        prior = np.asarray(prior_up, dtype=np.float64)
    prior = prior / np.linalg.norm(prior)

    all_normals = np.concatenate(normals)
    weights = np.concatenate([np.full(len(n), 1.0 / len(n)) for n in normals]) / len(normals)
    centres, neighbours = _direction_bins(config.bins, config.cluster_deg)
    bins = _nearest_bin(centres, all_normals)
    in_cone = centres @ prior >= np.cos(np.radians(config.prior_cone_deg))
    strength = neighbours @ np.bincount(bins, weights=weights, minlength=config.bins)
    if not np.any(in_cone & (strength > 0.0)):
        return failed(f"no horizontal plane: no planar surface within {config.prior_cone_deg:g} deg of the "
                      f"cameras' up in {len(normals)} frames with planes (only walls?)")
    peak = int(np.argmax(np.where(in_cone, strength, -1.0)))
    up = _mean_shift(centres[peak], all_normals, weights, config.inlier_deg)
    support = float(weights[all_normals @ up >= np.cos(np.radians(config.inlier_deg))].sum())

    # Each frame's own up, found as the global one but from its normals alone: frames agree when
    # their own horizontal planes point the same way in the world.
    frame_ups = []
    for frame_normals, frame_bins in zip(normals, np.split(bins, np.cumsum([len(n) for n in normals])[:-1])):
        frame_strength = np.where(in_cone, neighbours @ np.bincount(frame_bins, minlength=config.bins), 0)
        frame_peak = int(np.argmax(frame_strength))
        if frame_strength[frame_peak] >= config.frame_min_patches:
            frame_ups.append(_mean_shift(centres[frame_peak], frame_normals, np.ones(len(frame_normals)), config.inlier_deg))
    angles = np.array([angle_deg(frame_up, up) for frame_up in frame_ups])
    agreeing = int((angles <= config.agree_deg).sum())
    spread = float(np.sqrt(np.mean(angles**2))) if frame_ups else float("nan")
    if len(frame_ups) < config.min_agreeing_frames:
        return failed(f"no horizontal plane: only {len(frame_ups)} of {len(normals)} frames with planes see one "
                      f"(need {config.min_agreeing_frames})", support, agreeing, spread)
    if agreeing < config.min_agreeing_frames or agreeing < config.min_agreeing_fraction * len(frame_ups):
        return failed(f"frames disagree: {agreeing} of {len(frame_ups)} frames with a horizontal plane agree within "
                      f"{config.agree_deg:g} deg (spread {spread:.1f} deg; need {config.min_agreeing_frames} and "
                      f"{config.min_agreeing_fraction:.0%}): poses wrong?", support, agreeing, spread)
    if support < config.min_support_fraction:
        return failed(f"no horizontal plane: the strongest candidate holds {support:.1%} of the planar surface "
                      f"(< {config.min_support_fraction:.0%}) in {len(normals)} frames", support, agreeing, spread)

    tilt = angle_deg(up, world_up())
    reason = (f"up from horizontal planes: {agreeing} of {len(frame_ups)} frames agree (spread {spread:.1f} deg), "
              f"{support:.0%} of the planar surface, {tilt:.1f} deg from the world's z")
    return UpEstimate(True, reason, up, "planes", n_frames, len(normals), agreeing, support, spread,
                      time.perf_counter() - started)


def planar_normals(depth: np.ndarray, K: np.ndarray, config: UpConfig = UpConfig()) -> np.ndarray:
    """Unit normals (n, 3) in the camera frame of the planar patches of a depth image (metres, 0 or
    out of range = invalid), each oriented towards the camera; at most config.max_patches_per_frame,
    evenly sampled.

    A patch is config.patch_size^2 samples (every config.pixel_stride-th pixel) with valid depth; its
    normal is the least-variance axis of its points (a plane fit), computed for all patches at once
    from box-filtered moments.
    """
    stride = config.pixel_stride
    z = np.asarray(depth, dtype=np.float64)[::stride, ::stride]
    valid = depth_in_range(z)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    z_valid = np.where(valid, z, 0.0)
    points = backproject(K, rows.ravel() * stride, cols.ravel() * stride, z_valid.ravel()).reshape(*z.shape, 3)

    size = config.patch_size
    if z.shape[0] < size or z.shape[1] < size:
        return np.zeros((0, 3))
    complete = ndimage.uniform_filter(valid.astype(np.float64), size, mode="constant") > 1.0 - 1e-6
    half = size // 2
    complete[:half], complete[-half:], complete[:, :half], complete[:, -half:] = False, False, False, False
    if not complete.any():
        return np.zeros((0, 3))
    # The moments of each patch, evaluated only at the complete patches' centres.
    mean = np.stack([ndimage.uniform_filter(points[..., i], size, mode="constant")[complete] for i in range(3)], axis=1)
    covariance = np.empty((len(mean), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            second = ndimage.uniform_filter(points[..., i] * points[..., j], size, mode="constant")[complete]
            covariance[:, i, j] = covariance[:, j, i] = second - mean[:, i] * mean[:, j]
    eigenvalues, eigenvectors = np.linalg.eigh(covariance)
    rms = np.sqrt(np.maximum(eigenvalues[:, 0], 0.0))
    planar = rms <= config.max_patch_rms_m + config.patch_rms_per_m2 * mean[:, 2] ** 2
    normals, centres = eigenvectors[planar, :, 0], mean[planar]
    normals *= -np.sign(np.einsum("ij,ij->i", normals, centres))[:, None]  # towards the camera
    if len(normals) > config.max_patches_per_frame:
        normals = normals[np.linspace(0, len(normals) - 1, config.max_patches_per_frame).astype(int)]
    return normals


def _mean_shift(start: np.ndarray, normals: np.ndarray, weights: np.ndarray, radius_deg: float, iterations: int = 10) -> np.ndarray:
    """The weighted mean direction of the normals within radius_deg of it, found by iterating from
    `start` (mean shift on the sphere with a flat kernel)."""
    direction = start / np.linalg.norm(start)
    cos_radius = np.cos(np.radians(radius_deg))
    for _ in range(iterations):
        near = normals @ direction >= cos_radius
        if not near.any():
            break
        mean = weights[near] @ normals[near]
        updated = mean / np.linalg.norm(mean)
        if updated @ direction > 1.0 - 1e-12:
            return updated
        direction = updated
    return direction


@lru_cache(maxsize=4)
def _direction_bins(count: int, radius_deg: float) -> tuple[np.ndarray, sparse.csr_matrix]:
    """Bin centres (count, 3), evenly spread on the unit sphere (a Fibonacci lattice), and the
    sparse (count, count) matrix whose row i marks the bins within radius_deg of bin i."""
    k = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / count)
    azimuth = np.pi * (1.0 + np.sqrt(5.0)) * k
    centres = np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1)
    chord = 2.0 * np.sin(np.radians(radius_deg) / 2.0)
    pairs = cKDTree(centres).query_pairs(chord, output_type="ndarray")
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(count)])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(count)])
    return centres, sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(count, count))


def _nearest_bin(centres: np.ndarray, directions: np.ndarray) -> np.ndarray:
    return cKDTree(centres).query(directions)[1]


# -- estimate from an IMU ---------------------------------------------------------------------


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
    return UpEstimate(True, reason, up, "imu", n, n_still, agreeing, fraction, spread, seconds)


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


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two directions in degrees."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    cos = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
