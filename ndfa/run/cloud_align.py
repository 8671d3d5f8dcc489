"""Aligning two sessions' scene clouds: the global alignment (FPFH + RANSAC, Open3D) refined by an
ICP that turns about z and shifts only (both worlds are levelled: 4 DoF), and the overlap figures
that judge an alignment. Clouds are (N, 3) arrays, one point per voxel (`voxel_thin`).

Used by `ndfa.run.align` (the scene-level T_rel hypotheses) and `ndfa.run.scene_evidence` (an
alignment's own evidence); why these defaults: `docs/detector.md`, `docs/registration.md`.
"""

from __future__ import annotations

import dataclasses
import hashlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from ndfa.change.register import yaw_transform
from ndfa.core.geometry import make_pose, rotation_z


@dataclass(frozen=True)
class SceneEvidenceConfig:
    """The bars a scene alignment passes to be accepted without object pairs (`ndfa.run.scene_evidence`)."""

    min_fitness: float = 0.5      # share of the target's upright points within icp_distance_m of the source's
    max_rmse_m: float = 0.03      # their RMS distance
    agree_m: float = 0.05         # each half's own alignment this close to the whole's, at the half's center ...
    agree_deg: float = 2.0        # ... and turned this little against it about up
    # A half's own alignment that moves its points less than bend_m (RMS) from the whole's is within
    # the coarse ICP's reach (its first stage pairs within 4 x icp_distance_m): a bent cloud, not
    # another registration. Beyond it, a half fitting contradict_margin better than at the whole's contradicts.
    bend_m: float = 0.20
    contradict_margin: float = 0.05
    min_agreeing: int = 1         # halves (of four) that must agree (a box room's halves fit themselves turned)
    rival_ratio: float = 0.8      # the alignment turned or shifted to a rival must overlap less than this share of it
    min_half_points: int = 100    # fewer upright points (or points in a half) cannot be judged: weak


@dataclass(frozen=True)
class AlignConfig:
    """How the sessions' scene clouds are built and aligned."""

    frames: int = 40                 # frames fused per session, spread over it
    pixel_stride: int = 8            # every 8th pixel along each axis (80 x 60 of a 640 x 480 frame)
    voxel_m: float = 0.05            # the fused clouds are thinned to one point per voxel
    normal_radius_m: float = 0.10    # normals for FPFH: 2 voxels
    feature_radius_m: float = 0.25   # FPFH neighbourhood: 5 voxels
    ransac_distance_m: float = 0.10  # a feature match supports a RANSAC hypothesis this close: 2 voxels
    ransac_iterations: int = 100_000
    icp_distance_m: float = 0.05     # closest points farther than this are not paired (1 voxel)
    icp_iterations: int = 30
    # ICP's coarse stages (pairing within 4 and 2 x icp_distance_m) on the target thinned to voxels
    # of their pairing distance (`icp_coarse_to_fine`); False: every stage on the whole target cloud.
    icp_coarse_voxels: bool = True
    min_fitness: float = 0.4         # scene alignment: share of the target cloud within icp_distance_m of the source's
    binding_fitness: float = 0.6     # ... from which RANSAC's fits must agree with it (RegistrationPrior.binding)
    upright_max_nz: float = 0.5      # shared world: points whose normal has |z| below this are upright
    shared_min_fitness: float = 0.2  # shared world: share of the target's upright points near the source's
    peak_shift_m: float = 0.10       # shared world: the overlap must be less this far off the hypothesis ...
    peak_turn_deg: float = 3.0       # ... and turned this much about z
    seed: int = 0                    # Open3D's RANSAC sampling (attempt k uses seed + k)
    ransac_attempts: int = 3         # RANSAC runs until one aligns (see align_scenes)
    # The best alignment turned by these angles (each way) about the target's center and refined
    # again: ICP stalls in a poorer basin a degree or two off on clouds bent by drift (see global_alignment).
    turn_search_deg: tuple[float, ...] = (1.0, 2.0, 4.0)
    # A scene alignment is also judged on its own evidence, by these bars (`ndfa.run.scene_evidence`); None: not.
    evidence: SceneEvidenceConfig | None = field(default_factory=SceneEvidenceConfig)


def voxel_thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point per occupied voxel: the mean of the points in it."""
    if len(points) == 0:
        return points
    keys = np.floor(points / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse.ravel(), points)
    thinned: np.ndarray = sums / counts[:, None]
    return thinned


def upright(cloud: np.ndarray, config: AlignConfig = AlignConfig()) -> np.ndarray:
    """The points whose surface normal is off the vertical (|n_z| < `upright_max_nz`)."""
    import open3d as o3d  # lazily: a run registered by its objects alone never loads Open3D (~1 s)

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=config.normal_radius_m, max_nn=30))
    kept: np.ndarray = cloud[np.abs(np.asarray(pcd.normals)[:, 2]) < config.upright_max_nz]
    return kept


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    moved: np.ndarray = points @ transform[:3, :3].T + transform[:3, 3]
    return moved


def global_alignment(source_cloud: np.ndarray, target_cloud: np.ndarray,
                     config: AlignConfig = AlignConfig()) -> tuple[np.ndarray, float, float]:
    """(transform target -> source, fitness, rmse): FPFH + RANSAC, then 4-DoF ICP; clouds of 3 points or more."""
    import open3d as o3d  # lazily: a run registered by its objects alone never loads Open3D (~1 s)

    registration = o3d.pipelines.registration
    target, source = _described(target_cloud, config), _described(source_cloud, config)
    # The features' mutual nearest neighbours, once for every attempt: what Open3D's feature-based
    # RANSAC pairs at each call (`feature_correspondences`), found faster with the source's tree kept.
    pairs = o3d.utility.Vector2iVector(feature_correspondences(target.array, source.array, source.tree()))
    # Open3D's RANSAC runs on threads, so one run can land in a wrong basin where another does not
    # (the kitchen halves: fitness 0.79 in one run, 0.07 in the next). So several runs, plus the
    # identity (worlds that start at the same place), each refined by the 4-DoF ICP from a coarse
    # pairing distance down; the best overlap wins.
    starts = [np.eye(4)]
    best = (-1.0, float("nan"), np.eye(4))
    for attempt in range(config.ransac_attempts):
        o3d.utility.random.seed(config.seed + attempt)
        coarse = registration.registration_ransac_based_on_correspondence(
            target.cloud, source.cloud, pairs, config.ransac_distance_m,
            registration.TransformationEstimationPointToPoint(False), 3,
            [registration.CorrespondenceCheckerBasedOnEdgeLength(0.9),
             registration.CorrespondenceCheckerBasedOnDistance(config.ransac_distance_m)],
            registration.RANSACConvergenceCriteria(config.ransac_iterations, 0.999))
        starts.append(_yaw_only(np.asarray(coarse.transformation)))
        for start in starts:
            best = _better(best, source_cloud, target_cloud, icp_coarse_to_fine(source_cloud, target_cloud, start, config),
                           config)
        starts = []
        if best[0] >= config.min_fitness:
            break
    fitness, rmse, transform = turn_search(source_cloud, target_cloud, best[2], config)
    return transform, fitness, rmse


# Open3D's feature matching keeps the mutual pairs only where at least this share of the query's
# features has one; else it pairs every feature with its nearest (`correspondences_from_features`).
MUTUAL_SHARE = float(np.float32(0.1))


def feature_correspondences(query: np.ndarray, reference: np.ndarray, reference_tree: cKDTree | None = None,
                            share: float = MUTUAL_SHARE) -> np.ndarray:
    """(K, 2) pairs (i, j) of feature rows, `reference[j]` the nearest of `query[i]` and `query[i]` the
    nearest of `reference[j]`, by i; where fewer than `share` of the query's rows have such a pair,
    every row with its nearest. What Open3D's `correspondences_from_features(query, reference, True)`
    gives (its feature-based RANSAC's pairs), on k-d trees; the way back is asked only of the
    reference rows some query row chose. reference_tree: `reference`'s, where the caller keeps it.

    Where a nearest row has identical twins (features of points with no neighbours are all zero)
    the tie is Open3D's to break, so those few rows are asked of Open3D's own k-d tree: the pairs
    must be Open3D's exactly, for RANSAC draws its samples by their place in the list."""
    if reference_tree is None:
        reference_tree = cKDTree(reference)
    nearest = _nearest(reference_tree, reference, query)
    chosen = np.unique(nearest)
    back = np.full(len(reference), -1)
    back[chosen] = _nearest(cKDTree(query), query, reference[chosen])
    rows = np.arange(len(query))
    mutual = np.nonzero(back[nearest] == rows)[0]
    if len(mutual) < int(share * len(query)):
        mutual = rows
    pairs: np.ndarray = np.stack([mutual, nearest[mutual]], axis=1).astype(np.int32)
    return pairs


def _nearest(tree: cKDTree, rows: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """The index in `rows` (`tree`'s data) of each query's nearest; a nearest with identical twins
    in `rows` is asked again of Open3D's k-d tree, which breaks the tie its own way."""
    nearest: np.ndarray = tree.query(queries)[1]
    _, group, counts = np.unique(rows, axis=0, return_inverse=True, return_counts=True)
    tied = np.nonzero(counts[group.ravel()][nearest] > 1)[0]
    if len(tied):
        import open3d as o3d

        flann = o3d.geometry.KDTreeFlann(np.ascontiguousarray(rows.T))
        for k in tied:
            nearest[k] = flann.search_knn_vector_xd(queries[k], 1)[1][0]
    return nearest


@dataclass
class Described:
    """A cloud as the global alignment uses it: Open3D's point cloud with normals, its FPFH features
    (Open3D's and as an (N, 33) array) and, once asked for, the features' k-d tree."""

    cloud: Any
    features: Any
    array: np.ndarray
    _tree: cKDTree | None = None

    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.array)
        return self._tree


# The last clouds described, by content (`_described`), the last clouds' k-d trees (`point_tree`)
# and the last clouds thinned for ICP's coarse stages (`coarse_cloud`).
_DESCRIBED: dict[tuple[bytes, tuple[int, ...], float, float], Described] = {}
_DESCRIBED_KEPT = 3
_TREES: dict[tuple[bytes, tuple[int, ...]], cKDTree] = {}
_TREES_KEPT = 4
_COARSE: dict[tuple[bytes, tuple[int, ...], float], np.ndarray] = {}
_COARSE_KEPT = 10


def _content(points: np.ndarray) -> tuple[bytes, tuple[int, ...]]:
    return hashlib.blake2b(points.tobytes(), digest_size=16).digest(), points.shape


def _described(cloud: np.ndarray, config: AlignConfig) -> Described:
    """`cloud` described (`Described`). The source's serve every alignment onto it (the whole
    target's and its four halves', `ndfa.run.scene_evidence`), so the last few are kept: the same
    cloud gives the same features, computed once."""
    import open3d as o3d  # lazily: a run registered by its objects alone never loads Open3D (~1 s)

    points = np.ascontiguousarray(cloud, dtype=np.float64)
    key = (*_content(points), config.normal_radius_m, config.feature_radius_m)
    described = _DESCRIBED.pop(key, None)
    if described is None:
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=config.normal_radius_m, max_nn=30))
        features = o3d.pipelines.registration.compute_fpfh_feature(
            pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=config.feature_radius_m, max_nn=100))
        described = Described(pcd, features, np.ascontiguousarray(np.asarray(features.data).T))
        while len(_DESCRIBED) >= _DESCRIBED_KEPT:
            _DESCRIBED.pop(next(iter(_DESCRIBED)))  # the least recently used
    _DESCRIBED[key] = described
    return described


def point_tree(cloud: np.ndarray) -> cKDTree:
    """`cloud`'s k-d tree; the last few kept, by content: ICP and the overlap ask for the same
    source cloud's (or its upright points') dozens of times an alignment."""
    points = np.ascontiguousarray(cloud, dtype=np.float64)
    key = _content(points)
    tree = _TREES.pop(key, None)
    if tree is None:
        tree = cKDTree(points)
        while len(_TREES) >= _TREES_KEPT:
            _TREES.pop(next(iter(_TREES)))
    _TREES[key] = tree
    return tree


def turn_search(source_cloud: np.ndarray, target_cloud: np.ndarray, found: np.ndarray,
                config: AlignConfig = AlignConfig()) -> tuple[float, float, np.ndarray]:
    """(fitness, rmse, transform): `found` (target -> source), or better. On clouds bent by the
    odometry's drift each part of the scene fits at a slightly different turn, and ICP can stall
    where the parts that fit worse fit (docs/registration.md, "The turn search"). So `found`
    is turned by each of `turn_search_deg`, both ways, about the target's center, refined by
    `icp_coarse_to_fine`, and the best overlap wins."""
    fitness, rmse = overlap(source_cloud, target_cloud, found, config.icp_distance_m)
    best = (fitness, rmse, found)
    pivot = np.array([*apply_transform(found, target_cloud)[:, :2].mean(axis=0), 0.0])
    for degrees in config.turn_search_deg:
        for sign in (1, -1):
            turn = rotation_z(np.radians(sign * degrees))
            start = make_pose(turn, pivot - turn @ pivot) @ found
            best = _better(best, source_cloud, target_cloud, icp_coarse_to_fine(source_cloud, target_cloud, start, config),
                           config)
    return best


def _better(best: tuple[float, float, np.ndarray], source_cloud: np.ndarray, target_cloud: np.ndarray,
            transform: np.ndarray, config: AlignConfig) -> tuple[float, float, np.ndarray]:
    """(fitness, rmse, transform) of `transform` when it overlaps more than `best`, else `best`."""
    fitness, rmse = overlap(source_cloud, target_cloud, transform, config.icp_distance_m)
    return (fitness, rmse, transform) if fitness > best[0] else best


def icp_coarse_to_fine(source_cloud: np.ndarray, target_cloud: np.ndarray, initial: np.ndarray,
                       config: AlignConfig = AlignConfig()) -> np.ndarray:
    """`icp_yaw` from `initial`, pairing within 4, then 2, then 1 x `icp_distance_m`; with
    `icp_coarse_voxels`, the two coarse stages pair the target thinned to voxels of their pairing
    distance (`coarse_cloud`) with the whole source: a stage's pairs are that far apart anyway, and
    a fifth to a tenth of the points take most of ICP's time off where most runs use all their
    iterations (docs/speed.md, 2026-12-07)."""
    tree = point_tree(source_cloud)
    transform = initial
    for distance in (4 * config.icp_distance_m, 2 * config.icp_distance_m, config.icp_distance_m):
        target = coarse_cloud(target_cloud, distance, config) if config.icp_coarse_voxels else target_cloud
        transform = icp_yaw(source_cloud, target, transform, dataclasses.replace(config, icp_distance_m=distance), tree)
    return transform


def coarse_cloud(cloud: np.ndarray, voxel_m: float, config: AlignConfig = AlignConfig()) -> np.ndarray:
    """`cloud` thinned to one point per `voxel_m` voxel (`voxel_thin`); `cloud` itself at voxels no
    larger than the cloud's own (`config.voxel_m`). The last few kept, by content: every ICP run
    onto the same target asks for the same."""
    if voxel_m <= config.voxel_m:
        return cloud
    points = np.ascontiguousarray(cloud, dtype=np.float64)
    key = (*_content(points), voxel_m)
    thinned = _COARSE.pop(key, None)
    if thinned is None:
        thinned = voxel_thin(points, voxel_m)
        while len(_COARSE) >= _COARSE_KEPT:
            _COARSE.pop(next(iter(_COARSE)))
    _COARSE[key] = thinned
    return thinned


def icp_yaw(source_cloud: np.ndarray, target_cloud: np.ndarray, initial: np.ndarray,
            config: AlignConfig = AlignConfig(), tree: cKDTree | None = None) -> np.ndarray:
    """Point-to-point ICP that turns about z and shifts only, from `initial` (target -> source).
    tree: `source_cloud`'s `cKDTree`, where the caller has it."""
    if tree is None:
        tree = point_tree(source_cloud)
    transform = initial
    for _ in range(config.icp_iterations):
        moved = target_cloud @ transform[:3, :3].T + transform[:3, 3]
        distance, nearest = tree.query(moved, distance_upper_bound=config.icp_distance_m)
        paired = np.isfinite(distance)
        if paired.sum() < 3:
            break
        step = yaw_transform(moved[paired], source_cloud[nearest[paired]])
        transform = step @ transform
        if np.linalg.norm(step[:3, 3]) < 1e-4 and abs(np.arctan2(step[1, 0], step[0, 0])) < 1e-5:
            break
    return transform


def overlap(source_cloud: np.ndarray, target_cloud: np.ndarray, transform: np.ndarray,
            distance_m: float) -> tuple[float, float]:
    """(share of target points within `distance_m` of a source point under `transform`, their RMS distance)."""
    moved = apply_transform(transform, target_cloud)
    distance, _ = point_tree(source_cloud).query(moved, distance_upper_bound=distance_m)
    close = distance[np.isfinite(distance)]
    return len(close) / max(len(moved), 1), float(np.sqrt(np.mean(close**2))) if len(close) else float("nan")


def _yaw_only(transform: np.ndarray) -> np.ndarray:
    """The turn about z (and the shift) of a transform between two levelled worlds; its tilt is noise."""
    yaw = np.arctan2(transform[1, 0] - transform[0, 1], transform[0, 0] + transform[1, 1])
    return make_pose(rotation_z(float(yaw)), transform[:3, 3])
