"""World up from the data: the direction of gravity in a session's world frame, and the rotation
that levels the world so that the z-up core (core/conventions.py) can use its poses unchanged.

Why it is needed: with estimated poses the world is the first camera's frame (up is roughly that
camera's -y), and datasets use their own world frames. In such a world the segmentation finds no
horizontal support plane, the object trees cut the wrong axes and the NDF's up cue points sideways.

How (`estimate_up`, docs/world_up.md):

1. **The cameras' up** (`cameras_up`), the prior: people and robots hold cameras roughly upright,
   so each camera's x axis is nearly level and its -y axis points roughly up (off by the pitch).
   When the camera panned, up is the direction the x axes are all perpendicular to (the least
   eigenvector of their scatter: no pitch bias); without a pan, the cameras' mean -y made
   perpendicular to their mean x. A camera that was not held upright (x axes far from level, or -y
   far from up on average) is refused: nothing else here can be trusted then.
2. **Planes**: per frame, the depth image is cut into small patches; the planar ones give a normal
   (oriented towards the camera, rotated into the world) and an area. Each frame weighs the same,
   its patches by area. Up is the mode of the normals' density on the sphere within a cone about
   the cameras' up, the candidates near it preferred (a Gaussian weight): floors, desks and shelf
   tops agree on it, while walls, monitors, tilted papers and clutter spread elsewhere and a
   ceiling (seen from below) points down. The mode is refined by mean shift over its normals.
3. **Confidence**: the frames are resampled (a bootstrap) and the mode found again: the RMS angle
   of those modes is `uncertainty_deg`. Up is "high" confidence when that is small, no rival mode
   of comparable weight lies elsewhere, and most frames that see the plane agree with it (each
   frame's own mode: wrong poses show here). Otherwise "low", and `warning` says why.
4. **Fallback**: when the planes are scarce (too little horizontal surface, or too few frames see
   it) or split (two comparable modes, neither the one near the cameras' up), up is the cameras'
   up, with confidence "low" and a warning that says so.

A recording with an IMU has a better prior: `ndfa.trajectory.up_imu`.

No file I/O here: callers pass frames (e.g. `RecordingReader.frames(step=...)`) or arrays.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ndfa.core.conventions import world_up
from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.trajectory.level import levelling_rotation
from ndfa.trajectory.up_sphere import PatchConfig, direction_bins, local_maxima, mean_shift, nearest_bin, planar_patches

# The cameras' mean -y axis must be at least this long: for upright cameras it is about the cosine
# of their mean pitch; for cameras (or poses) pointing every way, about 1/sqrt(n).
MIN_UPRIGHT = 0.2
BOOTSTRAP_NORMALS = 20000  # normals near up the bootstrap's mean shifts use at most (evenly sampled)


@dataclass(frozen=True)
class UpConfig:
    """Settings of `estimate_up` (checked on the 7-Scenes kitchen, the simulator's rooms and its
    handheld office: docs/world_up.md).

    patches: how depth images are cut into planar patches (`up_sphere.planar_patches`).
    min_patches_per_frame: a frame with fewer planar patches gives no normals (nearly no depth).
    bins, kernel_deg: the density of the normals is evaluated on `bins` directions (a Fibonacci
        lattice, ~2.3 degrees apart at 8000), each counting the normals' weight within kernel_deg.
    prior_cone_deg: up is searched within this angle of the cameras' up (or of `prior_up`).
    prior_sigma_deg: the candidates' density is weighed by a Gaussian of their angle to that prior
        (this standard deviation): of two horizontal-looking modes the one nearer the prior wins.
    inlier_deg: the normals within this angle of up are its inliers (mean shift, support, frames).
    min_support_fraction: up's inliers must hold at least this fraction of the planar area (each
        frame weighing the same), and at least `min_frames` frames must have `frame_min_share` of
        their planar area among them; otherwise the planes are scarce.
    agree_deg: a frame agrees when its own mode (mean shift from up over its own normals) is
        within this angle of up; fewer than min_agreeing_fraction of the frames that see the plane
        agreeing makes the estimate "low" confidence (poses wrong?).
    split_deg, split_ratio: another mode more than split_deg from up with at least split_ratio of
        its weighted density splits the planes.
    camera_agree_deg: a split is resolved by the one mode within this angle of the cameras' up.
    bootstrap: frame resamplings for `uncertainty_deg`; high_confidence_deg: at most this for "high".
    max_roll_deg: the cameras' x axes (RMS) at most this far from level, when they panned.
    max_camera_tilt_deg: the cameras' -y axes (RMS) at most this far from up.
    min_pan: the second eigenvalue of the x axes' scatter (about the mean squared sine of the
        pan about its middle) from which the x axes define up.
    """

    patches: PatchConfig = PatchConfig()
    min_patches_per_frame: int = 20
    bins: int = 8000
    kernel_deg: float = 5.0
    prior_cone_deg: float = 60.0
    prior_sigma_deg: float = 30.0
    inlier_deg: float = 7.0
    min_support_fraction: float = 0.05
    min_frames: int = 3
    frame_min_share: float = 0.05
    agree_deg: float = 5.0
    min_agreeing_fraction: float = 0.5
    split_deg: float = 15.0
    split_ratio: float = 0.5
    camera_agree_deg: float = 10.0
    bootstrap: int = 25
    high_confidence_deg: float = 1.5
    max_roll_deg: float = 15.0
    max_camera_tilt_deg: float = 45.0
    min_pan: float = 0.01

    def __post_init__(self) -> None:
        for name in ("bins", "min_patches_per_frame", "min_frames"):
            if not getattr(self, name) >= 1:
                raise TrajectoryError(f"up estimate {name} must be >= 1, got {getattr(self, name)}")
        for name in ("kernel_deg", "prior_cone_deg", "prior_sigma_deg", "inlier_deg", "agree_deg", "split_deg",
                     "camera_agree_deg", "high_confidence_deg", "max_roll_deg", "max_camera_tilt_deg"):
            if not 0.0 < getattr(self, name) < 180.0:
                raise TrajectoryError(f"up estimate {name} must be in (0, 180) degrees, got {getattr(self, name)}")
        for name in ("min_support_fraction", "frame_min_share", "min_agreeing_fraction", "split_ratio", "min_pan"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise TrajectoryError(f"up estimate {name} must be in [0, 1], got {getattr(self, name)}")


@dataclass(frozen=True)
class UpEstimate:
    """World up of a session, and how it was found.

    ok: whether up was found; when False, `up_world` is None and `reason` says why in one line.
    reason: one line: what was found (ok) or what was missing.
    up_world: unit 3-vector, the world's up (minus gravity) in the session's world frame, or None.
    method: "planes" (normals of horizontal planes), "cameras" (the cameras' axes: the planes'
        fallback) or "imu" (`up_imu.up_from_accelerations`).
    frames: frames (or IMU samples) given.
    frames_used: frames with enough planar patches (IMU: still samples).
    frames_agreeing: frames whose own horizontal plane (IMU: sample) is within agree_deg of up.
    support_fraction: fraction of the planar area (each frame weighing the same) within inlier_deg
        of up (IMU: fraction of the samples that are still). 0 when not found.
    spread_deg: RMS angle between the frames' own ups (IMU: the still samples) and up; nan when
        there are none.
    seconds: time the estimate took.
    confidence: "high" or "low" ("" when not found); warning: why it is low, in one line.
    uncertainty_deg: RMS angle of up over resamplings of the frames (planes, cameras) or of the
        samples' spread over their root count (IMU); nan when not found.
    cameras_deg: angle between up and the cameras' up (nan when not known).
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
    confidence: str = ""
    warning: str = ""
    uncertainty_deg: float = float("nan")
    cameras_deg: float = float("nan")

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


@dataclass(frozen=True)
class CameraUp:
    """Up from the cameras' own axes (`cameras_up`): up, how it was found, and how upright the
    cameras were. up is None when they were not upright (`reason` says why)."""

    up: np.ndarray | None
    method: str  # "level x axes" (they panned) or "mean -y" (they did not)
    reason: str
    roll_deg: float  # RMS angle of the x axes from level (about up)
    tilt_deg: float  # RMS angle of the -y axes from up (pitch and roll)
    uncertainty_deg: float  # RMS angle of up over resamplings of the cameras


def cameras_up(rotations: np.ndarray, config: UpConfig = UpConfig()) -> CameraUp:
    """Up from the cameras' rotations (n, 3, 3) (camera-to-world), see the module docstring."""
    rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)
    n = len(rotations)
    mean_down = rotations[:, :, 1].mean(axis=0)
    if n == 0 or np.linalg.norm(mean_down) < MIN_UPRIGHT:
        return CameraUp(None, "", f"the cameras' -y axes point every way (mean length {np.linalg.norm(mean_down):.2f} < "
                        f"{MIN_UPRIGHT:g} over {n} frames): cameras not upright or poses wrong", float("nan"),
                        float("nan"), float("nan"))
    up, method = _up_of_axes(rotations, config)
    rng = np.random.default_rng(0)
    resampled = [_up_of_axes(rotations[rng.integers(0, n, n)], config)[0] for _ in range(config.bootstrap)]
    uncertainty = float(np.sqrt(np.mean([angle_deg(u, up) ** 2 for u in resampled])))
    roll = float(np.degrees(np.sqrt(np.mean(np.arcsin(np.clip(rotations[:, :, 0] @ up, -1.0, 1.0)) ** 2))))
    tilt = float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(-rotations[:, :, 1] @ up, -1.0, 1.0)) ** 2))))
    reason = f"{method} of {n} cameras: x axes {roll:.1f} deg from level, -y {tilt:.1f} deg from up (RMS)"
    if roll > config.max_roll_deg or tilt > config.max_camera_tilt_deg:
        return CameraUp(None, method, f"the camera was not held upright, or the poses are wrong ({reason}; at most "
                        f"{config.max_roll_deg:g} and {config.max_camera_tilt_deg:g} deg): no up can be trusted",
                        roll, tilt, uncertainty)
    return CameraUp(up, method, reason, roll, tilt, uncertainty)


def _up_of_axes(rotations: np.ndarray, config: UpConfig) -> tuple[np.ndarray, str]:
    x_axes, mean_up = rotations[:, :, 0], -rotations[:, :, 1].mean(axis=0)
    eigenvalues, eigenvectors = np.linalg.eigh(x_axes.T @ x_axes / len(x_axes))
    if eigenvalues[1] >= max(config.min_pan, 5.0 * eigenvalues[0]):
        up, method = eigenvectors[:, 0], "level x axes"
    else:  # no pan: the x axes fix only one direction perpendicular to up
        mean_x = x_axes.mean(axis=0) / max(np.linalg.norm(x_axes.mean(axis=0)), 1e-12)
        up, method = mean_up - (mean_up @ mean_x) * mean_x, "mean -y"
    up = up / max(np.linalg.norm(up), 1e-12)
    return (up if up @ mean_up >= 0.0 else -up), method


def estimate_up(frames: Iterable[Frame], config: UpConfig = UpConfig(), prior_up: np.ndarray | None = None) -> UpEstimate:
    """World up from the normals of the horizontal planes the frames see, the cameras' up as prior
    and fallback (see the module docstring).

    frames: the session's frames (depth in metres, K, camera-to-world poses). Every frame given is
        used, one at a time (only its normals are kept), so pass a subset for speed, e.g.
        `reader.frames(step=len(reader) // 60)`.
    prior_up: where to search for up instead of the cameras' up (e.g. an IMU's estimate); the
        cameras must still have been upright.
    """
    started = time.perf_counter()
    return up_from_patches(((frame.pose_world_camera[:3, :3], *frame_patches(frame, config)) for frame in frames),
                           config, prior_up, started)


def frame_patches(frame: Frame, config: UpConfig = UpConfig()) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals (n, 3) in the camera's frame, areas (n,)) of the frame's planar patches: what
    `estimate_up` takes of a frame but its pose, so they can be found where the frame is read,
    before its pose is known (`ndfa.run.world`: while the odometry reads it)."""
    return planar_patches(frame.depth, frame.K, config.patches)


def up_from_patches(views: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], config: UpConfig = UpConfig(),
                    prior_up: np.ndarray | None = None, started: float | None = None) -> UpEstimate:
    """`estimate_up` of frames given as (camera-to-world rotation (3, 3), `frame_patches`' normals
    and areas), one per frame."""
    rotations, normals, areas = [], [], []
    for rotation, frame_normals, frame_areas in views:
        rotations.append(rotation)
        if len(frame_normals) >= config.min_patches_per_frame:
            normals.append(frame_normals @ rotation.T)
            areas.append(frame_areas)
    return up_from_normals(rotations, normals, areas, config, prior_up, started)


def up_from_normals(rotations: list[np.ndarray], normals: list[np.ndarray], areas: list[np.ndarray],
                    config: UpConfig = UpConfig(), prior_up: np.ndarray | None = None,
                    started: float | None = None) -> UpEstimate:
    """`estimate_up` once the planar patches are found: the cameras' rotations (camera-to-world, one
    per frame given), and per frame with enough patches their unit normals in the world (n, 3) and
    areas (n,)."""
    started = time.perf_counter() if started is None else started
    n_frames = len(rotations)
    if n_frames == 0:
        return UpEstimate(False, "no frames given", None, "planes", 0, 0, 0, 0.0, float("nan"))
    cameras = cameras_up(np.array(rotations), config)
    if cameras.up is None:
        return UpEstimate(False, cameras.reason, None, "planes", n_frames, len(normals), 0, 0.0, float("nan"),
                          time.perf_counter() - started)
    prior = cameras.up if prior_up is None else np.asarray(prior_up, dtype=np.float64) / np.linalg.norm(prior_up)

    def fallback(why: str, support: float = 0.0, agreeing: int = 0, spread: float = float("nan")) -> UpEstimate:
        warning = f"{why}; up from the cameras ({cameras.reason}): good when the camera was held level"
        return UpEstimate(True, warning, cameras.up, "cameras", n_frames, len(normals), agreeing, support, spread,
                          time.perf_counter() - started, "low", warning, cameras.uncertainty_deg, 0.0)

    if not normals:
        return fallback(f"no planar surfaces in any of {n_frames} frames (no depth in range, or too little of it)")
    planes = _PlaneNormals(normals, areas, prior, config)
    if planes.score.max() <= 0.0:
        return fallback(f"no horizontal plane: no planar surface within {config.prior_cone_deg:g} deg of the cameras' "
                        f"up in {len(normals)} frames with planes (only walls?)")
    maxima = local_maxima(planes.score, planes.neighbours)
    up = planes.refine(planes.centres[maxima[0]])
    support, seeing, agreeing, spread = planes.agreement(up)
    if support < config.min_support_fraction or seeing < config.min_frames:
        return fallback(f"horizontal planes scarce: {support:.1%} of the planar area (need "
                        f"{config.min_support_fraction:.0%}) in {seeing} frames (need {config.min_frames})",
                        support, agreeing, spread)
    warnings = []
    rivals = [m for m in maxima[1:] if angle_deg(planes.centres[m], up) > config.split_deg
              and planes.score[m] >= config.split_ratio * planes.score[maxima[0]]]
    if rivals:
        rival = planes.refine(planes.centres[rivals[0]])
        split = (f"the planes split between two directions {angle_deg(up, rival):.1f} deg apart "
                 f"(weights {planes.score[rivals[0]] / planes.score[maxima[0]]:.2f} : 1)")
        near = [c for c in (up, rival) if angle_deg(c, cameras.up) <= config.camera_agree_deg]
        if len(near) != 1:
            return fallback(split, support, agreeing, spread)
        up = near[0]
        warnings.append(f"{split}: the one {angle_deg(up, cameras.up):.1f} deg from the cameras' up is taken")
        support, seeing, agreeing, spread = planes.agreement(up)
    # A camera held rolled looks, by its axes alone, like an upright one in another world; the planes
    # tell: its -y axes are then far from their up.
    tilt = float(np.sqrt(np.mean([angle_deg(-rotation[:, 1], up) ** 2 for rotation in rotations])))
    if tilt > config.max_camera_tilt_deg:
        return UpEstimate(False, f"the camera was not held upright: its -y axes are {tilt:.1f} deg (RMS) from the "
                          f"horizontal planes' up (at most {config.max_camera_tilt_deg:g}; {cameras.reason})", None,
                          "planes", n_frames, len(normals), agreeing, support, spread, time.perf_counter() - started)
    uncertainty = planes.bootstrap_uncertainty(up)
    if uncertainty > config.high_confidence_deg:
        warnings.append(f"up moves by {uncertainty:.1f} deg (RMS) when the frames are resampled")
    if agreeing < config.min_agreeing_fraction * seeing:
        warnings.append(f"frames disagree: {agreeing} of the {seeing} frames that see the plane agree within "
                        f"{config.agree_deg:g} deg (spread {spread:.1f} deg): poses wrong?")
    confidence = "low" if warnings else "high"
    reason = (f"up from horizontal planes ({confidence} confidence, +-{uncertainty:.1f} deg): {support:.0%} of the "
              f"planar area, {agreeing} of {seeing} frames agree (spread {spread:.1f} deg), "
              f"{angle_deg(up, cameras.up):.1f} deg from the cameras' up, {angle_deg(up, world_up()):.1f} deg from the "
              "world's z")
    return UpEstimate(True, reason, up, "planes", n_frames, len(normals), agreeing, support, spread,
                      time.perf_counter() - started, confidence, "; ".join(warnings), uncertainty,
                      angle_deg(up, cameras.up))


class _PlaneNormals:
    """The session's planar normals in the world, weighted (each frame the same, its patches by
    area), and their density on the sphere weighed by the prior (see `estimate_up`)."""

    def __init__(self, normals: list[np.ndarray], areas: list[np.ndarray], prior: np.ndarray, config: UpConfig):
        self.config = config
        self.normals = np.concatenate(normals)
        self.frame_of = np.concatenate([np.full(len(n), i) for i, n in enumerate(normals)])
        self.weights = np.concatenate([a / a.sum() for a in areas]) / len(normals)
        self.centres, self.neighbours = direction_bins(config.bins, config.kernel_deg)
        bins = nearest_bin(self.centres, self.normals)
        from_prior = np.degrees(np.arccos(np.clip(self.centres @ prior, -1.0, 1.0)))
        self.prior_weight = np.where(from_prior <= config.prior_cone_deg,
                                     np.exp(-0.5 * (from_prior / config.prior_sigma_deg) ** 2), 0.0)
        self.frame_histograms = sparse.csr_matrix((self.weights, (self.frame_of, bins)),
                                                  shape=(len(normals), config.bins))
        self.score = self._score(np.ones(len(normals)))

    def _score(self, frame_counts: np.ndarray) -> np.ndarray:
        return (self.neighbours @ (self.frame_histograms.T @ frame_counts)) * self.prior_weight

    def refine(self, start: np.ndarray, frame_counts: np.ndarray | None = None) -> np.ndarray:
        weights = self.weights if frame_counts is None else self.weights * frame_counts[self.frame_of]
        return mean_shift(start, self.normals, weights, self.config.inlier_deg)

    def agreement(self, up: np.ndarray) -> tuple[float, int, int, float]:
        """up's share of the planar area; the frames that see it; of those, the frames whose own mode
        is within agree_deg of it; and the RMS angle of their own modes."""
        inlier = self.normals @ up >= np.cos(np.radians(self.config.inlier_deg))
        share = np.bincount(self.frame_of[inlier], self.weights[inlier], minlength=self.frame_of[-1] + 1)
        frames = np.flatnonzero(share * len(share) >= self.config.frame_min_share)
        angles = np.array([angle_deg(mean_shift(up, self.normals[self.frame_of == f], self.weights[self.frame_of == f],
                                                self.config.inlier_deg), up) for f in frames])
        spread = float(np.sqrt(np.mean(angles**2))) if len(angles) else float("nan")
        return float(share.sum()), len(frames), int((angles <= self.config.agree_deg).sum()), spread

    def bootstrap_uncertainty(self, up: np.ndarray) -> float:
        """RMS angle between up and the modes of `config.bootstrap` resamplings of the frames."""
        rng = np.random.default_rng(0)
        n = self.frame_histograms.shape[0]
        # Mean shift only over the normals near up (for speed): a mode farther away counts as its bin.
        near_deg = 4.0 * self.config.inlier_deg
        near = np.flatnonzero(self.normals @ up >= np.cos(np.radians(near_deg)))
        near = near[::max(1, len(near) // BOOTSTRAP_NORMALS)]
        normals, weights, frame_of = self.normals[near], self.weights[near], self.frame_of[near]
        angles = []
        for _ in range(self.config.bootstrap):
            counts = np.bincount(rng.integers(0, n, n), minlength=n).astype(np.float64)
            score = self._score(counts)
            if score.max() <= 0.0:
                angles.append(180.0)
                continue
            peak = self.centres[int(np.argmax(score))]
            if angle_deg(peak, up) < near_deg - self.config.inlier_deg:
                peak = mean_shift(peak, normals, weights * counts[frame_of], self.config.inlier_deg)
            angles.append(angle_deg(peak, up))
        return float(np.sqrt(np.mean(np.square(angles))))


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two directions in degrees."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    cos = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
