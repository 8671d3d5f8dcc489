"""Camera poses from depth alone: KISS-ICP odometry on back-projected depth images.

KISS-ICP (Vizzo et al., RA-L 2023) was built for LiDAR scans, but it only needs a point cloud per
frame, so a depth image back-projected with K is enough. Its defaults assume a 100 m LiDAR; a
depth camera sees 0.2-4 m, so the ranges, the voxel size and the adaptive correspondence threshold
are rescaled here (`OdometryConfig`). Frames are instantaneous (global-shutter depth), so there is
no deskewing. Two additions, each measured to be needed on the simulator's `random` preset: depth is
block-averaged before back-projection (the noise of far pixels is cm-scale), and KISS-ICP's
point-to-point estimate is refined point-to-plane against its own map (`refine.py`): KISS-ICP alone
drifted 20 cm in the first 20 frames there, even on noise-free depth.

World frame: KISS-ICP starts at the identity, i.e. in the first camera's frame. That frame is then
anchored to the first frame's *given* pose (by default), so the estimate starts where the recording
did and keeps its world axes (z up for the simulator and most datasets; the object trees of the
detector bin objects by world x and y). Only the relative motion within a session is estimated:
the change detector registers the two sessions to each other by their objects, so an offset of the
whole trajectory costs nothing; drift within a session does.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import TrajectoryError
from ndfa.core.frame import Frame
from ndfa.core.geometry import backproject, project
from ndfa.trajectory.checks import GapClock
from ndfa.trajectory.refine import refine_point_to_plane

# Below this many valid depth points a frame is not registered: its pose is the constant-velocity
# prediction (the camera keeps its last motion), and the frame is counted as starved.
MIN_POINTS = 200


@dataclass(frozen=True)
class OdometryConfig:
    """Depth odometry settings for a short-range depth camera (defaults tuned on the simulator's
    `random` preset, seed 1: 640x480, 8 cm and 1-7 degrees between frames).

    min_range_m, max_range_m: points nearer or farther than this (Euclidean distance from the
        camera) are dropped: depth noise grows with z^2, so far points mostly add noise.
        max_range_m also bounds KISS-ICP's local map around the camera.
    voxel_size_m: voxel of KISS-ICP's local map. It registers the frame downsampled to 1.5x this,
        keeps the frame downsampled to 0.5x this in the map, at most `max_points_per_voxel` per voxel,
        and searches correspondences only in the 27 voxels around a point, so the voxel must exceed
        the constant-velocity prediction's error (a few cm at walking speed).
    pixel_stride: depth is averaged over pixel_stride x pixel_stride blocks before back-projection
        (see `depth_points`): 16x fewer points and 4x less noise at the default 4.
    initial_threshold_m: KISS-ICP's correspondence threshold sigma until the camera has moved enough
        to estimate it from its own prediction errors (KISS-ICP's default, 2 m, is LiDAR-scale).
    min_motion_m: motion between frames below which a frame does not update that estimate.
    max_iterations, convergence: KISS-ICP's ICP iteration cap and stopping criterion.
    refine: follow KISS-ICP's point-to-point estimate with point-to-plane ICP (refine.py) against
        the visible part of its map. On the simulator's 60-degree camera, point-to-point alone
        drifts about 20 cm in 20 frames (1.6 m): a narrow view of mostly planar surfaces leaves
        sliding and rotation nearly unconstrained for points matched to points; planes pin them down.
    refine_distance_m: correspondence distance of the refinement; a correction of more than twice
        this is rejected and KISS-ICP's pose kept.
    refine_iterations: iteration cap of the refinement.
    refine_sigma_m: scale of the refinement's robust (Geman-McClure) kernel, about the noise of the
        block-averaged points (5 mm at 3 m in the simulator) plus the map's.
    normal_neighbours: map points (thinned to one per voxel) per normal estimate.
    threads: KISS-ICP registration threads; 0 lets it use every core.
    anchor_to_first_pose: express the estimate in the recording's world by anchoring the first
        estimated pose at the first given pose; False leaves it in the first camera's frame.
    """

    min_range_m: float = 0.2
    max_range_m: float = 4.0
    voxel_size_m: float = 0.03
    max_points_per_voxel: int = 5
    pixel_stride: int = 4
    initial_threshold_m: float = 0.1
    min_motion_m: float = 0.02
    max_iterations: int = 100
    convergence: float = 1e-4
    refine: bool = True
    refine_distance_m: float = 0.05
    refine_iterations: int = 20
    refine_sigma_m: float = 0.01
    normal_neighbours: int = 15
    threads: int = 0
    anchor_to_first_pose: bool = True

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_range_m < self.max_range_m:
            raise TrajectoryError(f"odometry needs 0 <= min_range_m < max_range_m, got {self.min_range_m}, {self.max_range_m}")
        for name in ("voxel_size_m", "initial_threshold_m", "refine_distance_m", "refine_sigma_m"):
            if not getattr(self, name) > 0.0:
                raise TrajectoryError(f"odometry {name} must be > 0, got {getattr(self, name)}")
        for name in ("pixel_stride", "max_points_per_voxel", "max_iterations", "refine_iterations", "normal_neighbours"):
            if not getattr(self, name) >= 1:
                raise TrajectoryError(f"odometry {name} must be >= 1, got {getattr(self, name)}")

    def to_dict(self) -> dict:
        """Plain values, for provenance in a recording's meta."""
        return dataclasses.asdict(self)

    def kiss_config(self):  # -> kiss_icp.config.KISSConfig (imported lazily: it pulls in pydantic)
        """The KISS-ICP configuration these settings stand for."""
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig

        # Built from explicit sections rather than from the environment: KISSConfig is a pydantic
        # BaseSettings and would otherwise read KISS_ICP_* variables.
        return KISSConfig(
            data=DataConfig(min_range=self.min_range_m, max_range=self.max_range_m, deskew=False),
            mapping=MappingConfig(voxel_size=self.voxel_size_m, max_points_per_voxel=self.max_points_per_voxel),
            registration=RegistrationConfig(max_num_iterations=self.max_iterations,
                                            convergence_criterion=self.convergence, max_num_threads=self.threads),
            adaptive_threshold=AdaptiveThresholdConfig(initial_threshold=self.initial_threshold_m,
                                                       min_motion_th=self.min_motion_m),
        )


def depth_points(depth: np.ndarray, K: np.ndarray, block: int = 1, tolerance: float = 0.05) -> np.ndarray:
    """Camera-frame points (N, 3) float64 of a depth image in metres, one per `block` x `block`
    pixel block (OpenCV pinhole, pixel centres at integer coordinates; a block's point lies on the
    ray through the block's centre).

    A block's depth is the mean of its valid pixels within `tolerance` (relative) of the block's
    median, and a block with fewer than half of its pixels such inliers is dropped. Why: the
    per-pixel noise of a triangulating depth camera grows with z^2 (2-3 cm at 3-4 m in the
    simulator), and averaging b^2 independent pixels divides it by b, while the median test keeps a
    block at a depth edge from averaging two surfaces into a floating point. block=1 is plain
    back-projection of every valid pixel.
    """
    height, width = depth.shape[0] // block, depth.shape[1] // block
    blocks = depth[:height * block, :width * block].astype(np.float64)
    blocks = blocks.reshape(height, block, width, block).transpose(0, 2, 1, 3).reshape(height, width, block * block)
    valid = np.isfinite(blocks) & (blocks > 0.0)
    if block == 1:
        z, inliers = blocks[..., 0], valid[..., 0]
        keep = inliers
    else:
        masked = np.where(valid, blocks, np.inf)  # invalid pixels sort last; the median uses the valid ones
        counts = valid.sum(axis=2)
        ordered = np.sort(masked, axis=2)
        middle = np.take_along_axis(ordered, np.maximum(counts - 1, 0)[..., None] // 2, axis=2)[..., 0]
        inliers = valid & (np.abs(blocks - middle[..., None]) <= tolerance * middle[..., None])
        n_inliers = inliers.sum(axis=2)
        z = np.where(inliers, blocks, 0.0).sum(axis=2) / np.maximum(n_inliers, 1)
        keep = 2 * n_inliers >= block * block
    rows, cols = np.nonzero(keep)
    z = z[rows, cols]
    u = cols * block + (block - 1) / 2.0
    v = rows * block + (block - 1) / 2.0
    return backproject(K, v, u, z)


class DepthOdometry:
    """Frame-by-frame odometry on depth images; `update(frame)` returns that frame's estimated
    camera-to-world pose. One instance per session, frames in time order.

    Each frame: depth -> block-averaged camera-frame points -> KISS-ICP (constant-velocity
    prediction, adaptive threshold, robust point-to-point ICP against its voxel map) -> optionally a
    point-to-plane refinement against the visible part of the same map -> map update with the final
    pose. It follows `KissICP.register_frame` step by step (using its public members) so that the
    refined pose, not the coarse one, goes into KISS-ICP's map and motion model.

    Streaming on purpose: a 640x480 session of a few hundred frames does not fit in memory as
    frames, and `rewrite_poses` writes each frame as soon as its pose is known.
    """

    def __init__(self, config: OdometryConfig = OdometryConfig()) -> None:
        from kiss_icp.kiss_icp import KissICP

        self.config = config
        self._kiss = KissICP(config.kiss_config())
        self._anchor: np.ndarray | None = None  # T_world_camera0
        self.frames = 0
        self.starved_frames = 0  # frames with fewer than MIN_POINTS valid points, not registered
        self._clock = GapClock()
        self.refinements_rejected = 0  # frames whose point-to-plane refinement was not trusted
        self.seconds = 0.0  # spent in back-projection and registration

    def update(self, frame: Frame) -> np.ndarray:
        """Register `frame` to the local map; its (4, 4) camera-to-world pose."""
        started = time.perf_counter()
        config, kiss = self.config, self._kiss
        if self._anchor is None:
            self._anchor = frame.pose_world_camera.copy() if config.anchor_to_first_pose else np.eye(4)
        points = depth_points(frame.depth, frame.K, config.pixel_stride)
        distance = np.linalg.norm(points, axis=1)
        points = points[(distance >= config.min_range_m) & (distance <= config.max_range_m)]

        # Constant velocity; across a time gap the motion is unknown, so no motion is the guess.
        prediction = kiss.last_pose if self._clock.after_gap(frame.timestamp) else kiss.last_pose @ kiss.last_delta
        if len(points) < MIN_POINTS:
            # Keep moving as before; the map is not updated from a frame that shows (almost) nothing.
            self.starved_frames += 1
            pose = prediction
        else:
            source, map_points = kiss.voxelize(points)
            if kiss.local_map.empty():
                pose = prediction
            else:
                sigma = kiss.adaptive_threshold.get_threshold()
                pose = kiss.registration.align_points_to_map(
                    points=source, voxel_map=kiss.local_map, initial_guess=prediction,
                    max_correspondance_distance=3.0 * sigma, kernel=sigma)
                if config.refine:
                    pose = self._refine(pose, map_points, frame.K, frame.image_size)
            kiss.adaptive_threshold.update_model_deviation(np.linalg.inv(prediction) @ pose)
            kiss.local_map.update(map_points, pose)
        kiss.last_delta = np.linalg.inv(kiss.last_pose) @ pose
        kiss.last_pose = pose
        self.frames += 1
        self.seconds += time.perf_counter() - started
        return self._anchor @ pose

    def _refine(self, pose: np.ndarray, points: np.ndarray, K: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
        """Point-to-plane refinement (`refine.py`) of KISS-ICP's pose against the map points the
        camera can see. Rejected (KISS-ICP's pose kept) when less than half of the points find a
        plane or the correction exceeds twice the refinement distance."""
        import open3d as o3d  # here: slow to import, and the CLI imports this module for OdometryConfig's defaults

        config = self.config
        visible = _visible(self._kiss.local_map.point_cloud(), pose, K, image_size, config)
        if len(visible) < MIN_POINTS:
            self.refinements_rejected += 1
            return pose
        # Normals from the map thinned to one point per voxel: the map holds many frames' noisy points
        # per voxel, and a normal fitted to the nearest few of them fits noise (measured: this alone
        # made the refinement slide 5-25 cm per frame along a wall).
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(visible)).voxel_down_sample(config.voxel_size_m)
        cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=config.normal_neighbours))
        visible = np.asarray(cloud.points)
        result = refine_point_to_plane(
            points, visible, np.asarray(cloud.normals), initial=pose, max_distance_m=config.refine_distance_m,
            residual_sigma_m=config.refine_sigma_m, max_iterations=config.refine_iterations)
        correction = np.linalg.inv(pose) @ result.pose
        if result.inlier_fraction < 0.5 or np.linalg.norm(correction[:3, 3]) > 2.0 * config.refine_distance_m:
            self.refinements_rejected += 1
            return pose
        return result.pose

    @property
    def ms_per_frame(self) -> float:
        """Mean time of `update`, milliseconds (NaN before the first frame)."""
        return 1000.0 * self.seconds / self.frames if self.frames else float("nan")


def _visible(map_points: np.ndarray, pose: np.ndarray, K: np.ndarray, image_size: tuple[int, int],
             config: OdometryConfig) -> np.ndarray:
    """The map points (N, 3) inside the camera's view frustum (with a 10 % margin) and range: the
    only ones a frame's points can meet, and far fewer to estimate normals on than the whole map."""
    camera = (map_points - pose[:3, 3]) @ pose[:3, :3]  # world -> camera: R^T (p - t)
    z = camera[:, 2]
    in_front = (z > config.min_range_m) & (z < config.max_range_m + config.refine_distance_m)
    camera, kept = camera[in_front], map_points[in_front]
    u, v = project(K, camera).T
    height, width = image_size
    inside = (u > -0.1 * width) & (u < 1.1 * width) & (v > -0.1 * height) & (v < 1.1 * height)
    return kept[inside]


def iterate_poses(frames: Iterable[Frame], config: OdometryConfig = OdometryConfig()) -> Iterator[tuple[Frame, np.ndarray]]:
    """Each frame with its estimated camera-to-world pose, as they are estimated."""
    odometry = DepthOdometry(config)
    for frame in frames:
        yield frame, odometry.update(frame)


def estimate_poses(frames: Iterable[Frame], config: OdometryConfig = OdometryConfig()) -> list[np.ndarray]:
    """Estimated (4, 4) camera-to-world pose of every frame, in order (see the module docstring for
    the world frame). Frames are consumed one at a time; only the poses are kept."""
    return [pose for _, pose in iterate_poses(frames, config)]
