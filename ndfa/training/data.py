"""Training data of the NDF occupancy network: partial views of procedural mugs, with occupancy labels.

The paper's recipe (Sec. III-C, Fig. 3 and V-C): a randomly posed mug stands on a table with 2-4
other objects around it that may hide parts of it; a camera somewhere around the table, 0.2 to
5 m from its edge and a little above its top, looks at the mug. The depth pixels that the
segmentation assigns to the mug, back-projected, are the partial point cloud the network sees;
the labels are the occupancy of the full mug at query points around it.

One view (`View`); every array is in the CAMERA frame (OpenCV: x right, y down, z forward), metres:
- points (n_points, 3): the mug's visible depth points, with sensor noise, resampled to exactly
  n_points (`n_visible` says how many there were);
- queries (n_queries, 3) and occupancy (n_queries,): half near the mug's surface, half uniform in
  its enlarged bounding box, labelled exactly by `Mug.occupancy`;
- center_camera (3,): the true center of the full mug, see below;
- pose_camera_object (4, 4): mug frame -> camera frame.

The center of a mug (`mug_center`) is the centroid of its solid volume (the union of its parts).
The body's part is integrated exactly over its closed mesh; what the other parts (the handle) add
outside the body is estimated with one random point per cell of a 1 mm grid: within 0.05 mm of
the exact centroid. Not the mean of the visible points, not the centre of the bounding box: the
detector's center error is measured against it.

Speed: only the target mug's pixels are rendered. Rays are cast through a camera cropped to the
projection of the mug's bounding box (same pose and focal lengths, shifted principal point), and
per-mug work (surface samples, center) is cached: one core makes about 70 views per second.

Determinism: a view depends only on (seed, mug index, view number) and the set of mugs that may
lend it occluders, never on the order of generation or on the number of worker processes.
"""

from __future__ import annotations

import functools
import itertools
import multiprocessing
import zipfile
import zlib
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ndfa.io.atomic import atomic_path
from ndfa.core.errors import DataError
from ndfa.core.geometry import invert_pose, look_at, make_pose, rotation_z, transform_points
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.mug import BASE_STYLES, HANDLE_SHAPES, PROFILES, Mug, MugParams, revolve_profile
from ndfa.sim.noise import DepthNoise
from ndfa.sim.render import RenderObject, SceneRenderer
from ndfa.sim.scene import Table
from ndfa.sim.mug import sample_mug_params
from ndfa.sim.splits import make_split_mug, mug_seed

if TYPE_CHECKING:
    import torch

TARGET_ID = 1  # instance id of the target mug in the rendered instance image; occluders get 2, 3, ...
CENTER_GRID_M = 0.001  # cell size of the grid that adds the handle to a mug's center
SURFACE_SAMPLES = 8192  # surface points cached per mug, the seeds of the near-surface queries
# Box and cylinder occluders have a mug's size: full extents in metres.
PRIMITIVE_HEIGHT_M = (0.05, 0.15)
BOX_SIDE_M = (0.04, 0.12)
CYLINDER_RADIUS_M = (0.025, 0.06)

# Per-view arrays of a dataset (`generate_views`, `load_dataset`): name -> dtype. V views.
DATASET_ARRAYS = {
    "points": np.float32,              # (V, n_points, 3) camera frame
    "n_visible": np.int32,             # (V,) mug points seen before resampling
    "pose_camera_object": np.float32,  # (V, 4, 4) mug frame -> camera frame
    "center": np.float32,              # (V, 3) View.center_camera
    "queries": np.float32,             # (V, n_queries, 3) camera frame
    "occupancy": np.bool_,             # (V, n_queries)
    "mug_index": np.int32,             # (V,) index of the mug within its split
    "view_id": np.int32,               # (V,) view number of that mug: (seed, mug_index, view_id) redraws it
}


@dataclass(frozen=True)
class ViewConfig:
    """How training views are drawn. Lengths in metres, angles in radians, ranges (low, high).

    camera: the depth camera (the full image; a view renders only the crop around its mug).
    table: the table the mugs stand on, in the world frame (only its top matters).
    distance_range_m: horizontal distance of the camera from the table's edge (the paper's d_c
        and d_f), drawn log-uniform: as many cameras within 1 m as between 1 and 5 m. The mug
        stands anywhere on the top, so it is further away (median about 1.3 m).
    height_range_m: camera height above the table top, uniform. The paper keeps the camera within
        0.1 m of the top; the detector's routes fly 0.2-0.3 m above the tables.
    aim_jitter_rad: standard deviation of the angle by which the camera aims off the mug's
        center, so that the mug is not always in the middle of the image (or even all in it).
    occluder_count_range: how many other objects stand around the mug, inclusive.
    occluder_mug_probability: chance that an occluder is another mug (when any are given) rather
        than a box or a cylinder.
    occluder_gap_range_m: free space between the footprint circles of the mug and an occluder.
    noise: the depth sensor model.
    n_points: points per view, resampled from the visible ones.
    n_queries: query points per view: half near the surface, half uniform in the box.
    min_points: a view that shows fewer points of the mug is drawn again.
    near_surface_sigmas_m: standard deviations of the Gaussian offsets of the near-surface queries
        from the surface, in equal shares: fine detail of the walls and the space around them.
    box_padding: the uniform queries fill the mug's bounding box scaled by 1 + box_padding.
    max_attempts: draws of a scene before a view is given up (a sane config needs a few).
    """

    camera: PinholeCamera = PinholeCamera()
    table: Table = Table(table_id=1, center_xy=(0.0, 0.0))
    distance_range_m: tuple[float, float] = (0.2, 5.0)
    height_range_m: tuple[float, float] = (0.05, 0.35)
    aim_jitter_rad: float = 0.08
    occluder_count_range: tuple[int, int] = (2, 4)
    occluder_mug_probability: float = 0.5
    occluder_gap_range_m: tuple[float, float] = (0.01, 0.15)
    noise: DepthNoise = DepthNoise()
    n_points: int = 400
    n_queries: int = 512
    min_points: int = 30
    near_surface_sigmas_m: tuple[float, ...] = (0.003, 0.015)
    box_padding: float = 0.25
    max_attempts: int = 100

    def __post_init__(self) -> None:
        ranges = {"distance_range_m": self.distance_range_m, "height_range_m": self.height_range_m,
                  "occluder_count_range": self.occluder_count_range, "occluder_gap_range_m": self.occluder_gap_range_m}
        for name, (low, high) in ranges.items():
            if not 0 <= low <= high:
                raise DataError(f"{name} must be a range 0 <= low <= high, got ({low}, {high})")
        if self.distance_range_m[0] <= 0:
            raise DataError("distance_range_m must start above 0 (it is drawn log-uniform)")
        if min(self.n_points, self.n_queries, self.min_points, self.max_attempts) < 1:
            raise DataError("n_points, n_queries, min_points and max_attempts must be at least 1")
        if not self.near_surface_sigmas_m or min(self.near_surface_sigmas_m) <= 0:
            raise DataError(f"near_surface_sigmas_m must be positive, got {self.near_surface_sigmas_m}")


@dataclass(frozen=True)
class View:
    """One training sample; arrays float32 (occupancy bool), camera frame, metres."""

    points: np.ndarray              # (n_points, 3) visible mug points, noisy, resampled
    n_visible: int                  # mug points seen before resampling
    pose_camera_object: np.ndarray  # (4, 4) mug frame -> camera frame
    center_camera: np.ndarray       # (3,) centroid of the mug's solid volume (`mug_center`)
    queries: np.ndarray             # (n_queries, 3) near-surface half first, then the uniform half
    occupancy: np.ndarray           # (n_queries,) whether each query is inside the mug
    mug_index: int = -1             # index of the mug within its split (-1: not given)
    view_id: int = -1               # view number of that mug (-1: not given)


# ----------------------------------------------------------------------------------------------
# Per-mug cache


@dataclass(frozen=True)
class _MugSamples:
    """What labelling views of one mug needs, computed once per mug. Mug frame, metres."""

    center: np.ndarray   # (3,) centroid of the solid volume
    box_min: np.ndarray  # (3,) corners of the mesh's axis-aligned bounding box
    box_max: np.ndarray  # (3,)
    surface: np.ndarray  # (S, 3) points on the surface of the solid


# Keyed by id(mug); the entry holds the mug itself, so the id cannot be reused while cached.
_SAMPLES_CACHE: OrderedDict[int, tuple[Mug, _MugSamples]] = OrderedDict()
_SAMPLES_CACHE_SIZE = 256


def mug_center(mug: Mug) -> np.ndarray:
    """(3,) the mug's center in the mug frame: the centroid of its solid volume (cached)."""
    return _mug_samples(mug).center.copy()


def _mug_samples(mug: Mug) -> _MugSamples:
    if id(mug) in _SAMPLES_CACHE:
        _SAMPLES_CACHE.move_to_end(id(mug))
        return _SAMPLES_CACHE[id(mug)][1]
    box_min, box_max = mug.mesh.bounds
    rng = np.random.default_rng(0)  # a fixed seed: the samples are part of the mug, not of a view
    samples = _MugSamples(
        center=_solid_centroid(mug, CENTER_GRID_M, rng),
        box_min=box_min,
        box_max=box_max,
        surface=_surface_samples(mug, SURFACE_SAMPLES, rng),
    )
    _SAMPLES_CACHE[id(mug)] = (mug, samples)
    if len(_SAMPLES_CACHE) > _SAMPLES_CACHE_SIZE:
        _SAMPLES_CACHE.popitem(last=False)
    return samples


def _solid_centroid(mug: Mug, spacing: float, rng: np.random.Generator) -> np.ndarray:
    """(3,) centroid of the union of the mug's parts. The first part (the body) is integrated
    exactly over its closed mesh; the rest adds the points inside the mug but not inside the first
    part, among one random point per cell of a grid over the other parts' box (random, not the
    cell centres: thin walls alias on a regular grid)."""
    volume, moment = _volume_and_moment(mug.parts[0])
    if len(mug.parts) > 1:
        low, high = Mesh.concatenate(mug.parts[1:]).bounds
        axes = [np.arange(a + spacing / 2, b, spacing) for a, b in zip(low, high)]
        cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        points = cells + rng.uniform(-spacing / 2, spacing / 2, size=cells.shape)
        first_part = Mug(mug.model_id, mug.seed, mug.params, mug.parts[:1])
        added = points[mug.occupancy(points) & ~first_part.occupancy(points)]
        volume += len(added) * spacing**3
        moment = moment + added.sum(axis=0) * spacing**3
    return moment / volume


def _volume_and_moment(mesh: Mesh) -> tuple[float, np.ndarray]:
    """Volume (m^3) and first moment (3,) of the solid inside a closed mesh: the sum over the
    tetrahedra spanned by the origin and each triangle (divergence theorem)."""
    a, b, c = (mesh.vertices[mesh.triangles[:, i]] for i in range(3))
    signed_volumes = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6
    volume, moment = signed_volumes.sum(), signed_volumes @ ((a + b + c) / 4)
    return (volume, moment) if volume > 0 else (-volume, -moment)  # inward winding flips both signs


def _surface_samples(mug: Mug, count: int, rng: np.random.Generator) -> np.ndarray:
    """Up to `count` points (S, 3) spread uniformly by area over the surface of the solid."""
    corners = mug.mesh.vertices[mug.mesh.triangles]  # (F, 3, 3)
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    double_area = np.linalg.norm(cross, axis=1)
    faces = rng.choice(len(corners), size=count, p=double_area / double_area.sum())
    a, b = rng.random((2, count, 1))
    outside_triangle = a + b > 1  # fold the far half of the parallelogram back into the triangle
    a[outside_triangle], b[outside_triangle] = 1 - a[outside_triangle], 1 - b[outside_triangle]
    c = corners[faces]
    points = c[:, 0] + a * (c[:, 1] - c[:, 0]) + b * (c[:, 2] - c[:, 0])
    # The parts overlap (the handle's ends are buried in the wall): keep the points with air
    # half a millimetre outside them (walls are >= 3 mm thick), the surface of the union.
    normals = cross[faces] / double_area[faces, None]
    return points[~mug.occupancy(points + 0.0005 * normals)]


# ----------------------------------------------------------------------------------------------
# One view


def render_view(mug: Mug, others: list[Mug], rng: np.random.Generator, config: ViewConfig = ViewConfig(),
                *, mug_index: int = -1, view_id: int = -1) -> View:
    """A partial view of `mug` on a table among occluders, with labels (see the module doc).

    others: mugs that may stand around it as occluders (may be empty: boxes and cylinders only).
    rng: the only source of randomness. mug_index, view_id: copied into the view.
    Raises DataError if `config.max_attempts` scenes in a row show the mug with too few points.
    """
    samples = _mug_samples(mug)
    for _ in range(config.max_attempts):
        objects, pose_world_object = _place_objects(mug, others, rng, config)
        center_world = transform_points(pose_world_object, samples.center[None])[0]
        pose_world_camera = _camera_pose(config.table, center_world, rng, config)
        pose_camera_object = invert_pose(pose_world_camera) @ pose_world_object
        # The margin keeps the noise model's edge test from reaching past the crop.
        crop = _crop_camera(config.camera, pose_camera_object, samples.box_min, samples.box_max,
                            margin=config.noise.edge_width_px + 2)
        if crop is None:
            continue
        visible = _visible_points(SceneRenderer(objects), crop, pose_world_camera, rng, config.noise)
        if len(visible) >= config.min_points:
            break
    else:
        raise DataError(f"{mug.model_id}: no view in {config.max_attempts} attempts shows {config.min_points} points")

    chosen = rng.choice(len(visible), config.n_points, replace=len(visible) < config.n_points)
    queries = transform_points(pose_camera_object, _query_points(samples, rng, config)).astype(np.float32)
    # Label the stored float32 queries, so that a label is exactly that of the stored point.
    occupancy = mug.occupancy(transform_points(invert_pose(pose_camera_object), queries.astype(np.float64)))
    return View(
        points=visible[chosen].astype(np.float32),
        n_visible=len(visible),
        pose_camera_object=pose_camera_object.astype(np.float32),
        center_camera=transform_points(pose_camera_object, samples.center[None])[0].astype(np.float32),
        queries=queries,
        occupancy=occupancy,
        mug_index=mug_index,
        view_id=view_id,
    )


def _place_objects(mug: Mug, others: list[Mug], rng: np.random.Generator,
                   config: ViewConfig) -> tuple[list[RenderObject], np.ndarray]:
    """The table, the mug (random yaw and position on the top) and occluders around it, all in
    the world frame, and the mug's pose_world_object (4, 4)."""
    table = config.table
    half_size = np.array(table.size_xy) / 2
    radius = _footprint_radius(mug.mesh)
    xy = rng.uniform(-(half_size - radius), half_size - radius)
    pose_world_object = _pose_on_table(table, xy, rng.uniform(0, 2 * np.pi))
    objects = [RenderObject(_table_mesh(table)), RenderObject(mug.mesh.transformed(pose_world_object), TARGET_ID)]
    placed = [(xy, radius)]  # footprint circles (centre in the table-top frame, radius), the mug first
    low, high = config.occluder_count_range
    for _ in range(rng.integers(low, high + 1)):
        mesh = _occluder_mesh(others, rng, config)
        spot = _free_spot(placed, _footprint_radius(mesh), half_size, rng, config)
        if spot is None:  # no room near the mug: fewer occluders this time
            continue
        placed.append((spot, _footprint_radius(mesh)))
        pose = _pose_on_table(table, spot, rng.uniform(0, 2 * np.pi))
        objects.append(RenderObject(mesh.transformed(pose), instance_id=len(objects)))  # 2, 3, ...
    return objects, pose_world_object


def _occluder_mesh(others: list[Mug], rng: np.random.Generator, config: ViewConfig) -> Mesh:
    """Another mug, or a box or a cylinder of a mug's size; in its own frame, base at z = 0."""
    if others and rng.random() < config.occluder_mug_probability:
        return others[rng.integers(len(others))].mesh
    height = rng.uniform(*PRIMITIVE_HEIGHT_M)
    if rng.random() < 0.5:
        sx, sy = rng.uniform(*BOX_SIDE_M, size=2)
        return box_mesh((sx, sy, height), (0.0, 0.0, height / 2))
    radius = rng.uniform(*CYLINDER_RADIUS_M)
    return revolve_profile(np.array([[0.0, 0.0], [radius, 0.0], [radius, height], [0.0, height]]), segments=24)


def _free_spot(placed: list[tuple[np.ndarray, float]], radius: float, half_size: np.ndarray,
               rng: np.random.Generator, config: ViewConfig, tries: int = 20) -> np.ndarray | None:
    """A position (2,) on the table top near the mug (placed[0]) for a footprint of `radius`
    that overlaps nothing placed yet; None if `tries` random spots all fail."""
    mug_xy, mug_radius = placed[0]
    for _ in range(tries):
        angle = rng.uniform(0, 2 * np.pi)
        distance = mug_radius + radius + rng.uniform(*config.occluder_gap_range_m)
        xy = mug_xy + distance * np.array([np.cos(angle), np.sin(angle)])
        on_table = np.all(np.abs(xy) <= half_size - radius)
        if on_table and all(np.linalg.norm(xy - other) >= r + radius for other, r in placed):
            return xy
    return None


def _footprint_radius(mesh: Mesh) -> float:
    """Radius of the vertical cylinder about the frame's z axis that holds the mesh."""
    return float(np.max(np.hypot(mesh.vertices[:, 0], mesh.vertices[:, 1])))


def _pose_on_table(table: Table, xy: np.ndarray, yaw: float) -> np.ndarray:
    """pose_world_object of an object standing on the top at `xy` (table-top frame), turned by `yaw`."""
    return table.pose_world_top @ make_pose(rotation_z(yaw), np.array([xy[0], xy[1], 0.0]))


@functools.lru_cache(maxsize=4)
def _table_mesh(table: Table) -> Mesh:
    return table.mesh()


def _camera_pose(table: Table, target_world: np.ndarray, rng: np.random.Generator, config: ViewConfig) -> np.ndarray:
    """pose_world_camera of a camera around the table, above its top, aiming near `target_world`."""
    distance = np.exp(rng.uniform(*np.log(config.distance_range_m)))
    xy = _point_around_rectangle(np.array(table.size_xy) / 2, distance, rng)
    eye = transform_points(table.pose_world_top, np.array([[xy[0], xy[1], rng.uniform(*config.height_range_m)]]))[0]
    # Aiming off by a small angle means an offset that grows with the distance.
    aim = target_world + config.aim_jitter_rad * np.linalg.norm(target_world - eye) * rng.standard_normal(3)
    return look_at(eye, aim)


def _point_around_rectangle(half_size: np.ndarray, distance: float, rng: np.random.Generator) -> np.ndarray:
    """A point (2,) drawn uniformly on the curve `distance` outside the rectangle |x| <= hx,
    |y| <= hy: its sides pushed out by `distance`, joined by quarter circles around the corners."""
    hx, hy = half_size
    arc = np.pi / 2 * distance
    # Draw on the first quadrant's piece (side, quarter circle, side), then mirror it at random.
    s = rng.uniform(0, hy + arc + hx)
    if s < hy:
        point = np.array([hx + distance, s])
    elif s < hy + arc:
        angle = (s - hy) / distance
        point = np.array([hx + distance * np.cos(angle), hy + distance * np.sin(angle)])
    else:
        point = np.array([s - hy - arc, hy + distance])
    return point * rng.choice([-1.0, 1.0], size=2)


def _crop_camera(camera: PinholeCamera, pose_camera_object: np.ndarray, box_min: np.ndarray,
                 box_max: np.ndarray, margin: int) -> PinholeCamera | None:
    """The part of `camera`'s image that can see the box (object frame) plus `margin` pixels, as a
    camera of its own: same focal lengths, principal point shifted by the crop's corner. Points
    back-projected through it are in the same camera frame. None if the box is out of view."""
    corners = transform_points(pose_camera_object, np.array(list(itertools.product(*zip(box_min, box_max)))))
    if np.any(corners[:, 2] <= 1e-3):  # the box reaches behind the camera: its projection is unbounded
        return camera
    uv, _ = camera.project(corners)
    u0 = max(int(np.floor(uv[:, 0].min())) - margin, 0)
    u1 = min(int(np.ceil(uv[:, 0].max())) + margin, camera.width - 1)
    v0 = max(int(np.floor(uv[:, 1].min())) - margin, 0)
    v1 = min(int(np.ceil(uv[:, 1].max())) + margin, camera.height - 1)
    if u0 > u1 or v0 > v1:
        return None
    return PinholeCamera(u1 - u0 + 1, v1 - v0 + 1, camera.fx, camera.fy, camera.cx - u0, camera.cy - v0)


def _visible_points(renderer: SceneRenderer, camera: PinholeCamera, pose_world_camera: np.ndarray,
                    rng: np.random.Generator, noise: DepthNoise) -> np.ndarray:
    """(M, 3) float64 noisy depth points of the target mug, camera frame."""
    rendered = renderer.render(camera, pose_world_camera)
    depth = noise.apply(rendered.depth, rendered.normals_camera, rng, camera)
    points, pixels = camera.backproject(depth)
    return points[rendered.instance[pixels[:, 0], pixels[:, 1]] == TARGET_ID]


def _query_points(samples: _MugSamples, rng: np.random.Generator, config: ViewConfig) -> np.ndarray:
    """(n_queries, 3) query points in the mug frame: near the surface first, then uniform in the box."""
    n_near = config.n_queries // 2
    sigmas = np.resize(np.asarray(config.near_surface_sigmas_m), n_near)  # equal shares, in turn
    near = samples.surface[rng.integers(len(samples.surface), size=n_near)]
    near = near + rng.standard_normal((n_near, 3)) * sigmas[:, None]
    center = (samples.box_min + samples.box_max) / 2
    half = (samples.box_max - samples.box_min) / 2 * (1 + config.box_padding)
    uniform = rng.uniform(center - half, center + half, size=(config.n_queries - n_near, 3))
    return np.concatenate([near, uniform])


# ----------------------------------------------------------------------------------------------
# Datasets


def generate_views(split: str, mug_indices: list[int], views_per_mug: int, seed: int,
                   config: ViewConfig = ViewConfig(), workers: int = 2) -> dict[str, np.ndarray]:
    """`views_per_mug` views of each mug `mug_indices` of `split`, stacked (`DATASET_ARRAYS`, mug
    by mug in the given order, plus "split" and "seed" as 0-d arrays).

    Occluder mugs come from the same list (the target itself excluded), so no other split leaks
    in. View k of mug i draws everything from `default_rng([seed, i, k])`: the result does not
    depend on the order of `mug_indices` or on `workers` (processes; 1 = this process). Workers
    are spawned, so a script that calls this with workers > 1 needs the `if __name__ ==
    "__main__":` guard.
    """
    mug_indices = [int(i) for i in mug_indices]
    if not mug_indices or len(set(mug_indices)) != len(mug_indices):
        raise DataError(f"mug_indices must be a non-empty list of distinct indices, got {mug_indices[:10]}")
    if views_per_mug < 1 or seed < 0:
        raise DataError(f"need views_per_mug >= 1 and seed >= 0, got {views_per_mug} and {seed}")
    pool = sorted(mug_indices)
    tasks = [(split, index, pool, views_per_mug, seed, config) for index in mug_indices]
    if workers <= 1 or len(tasks) == 1:
        parts = [_views_of_mug(*task) for task in tasks]
    else:
        # Fresh interpreters: forking a process whose Open3D (TBB) threads have run can deadlock.
        with multiprocessing.get_context("spawn").Pool(min(workers, len(tasks))) as processes:
            parts = processes.starmap(_views_of_mug, tasks, chunksize=1)
    dataset = {name: np.concatenate([part[name] for part in parts]) for name in DATASET_ARRAYS}
    return dataset | {"split": np.array(split), "seed": np.array(seed)}


def _views_of_mug(split: str, mug_index: int, pool: list[int], views_per_mug: int, seed: int,
                  config: ViewConfig) -> dict[str, np.ndarray]:
    """All views of one mug, stacked: one task, so that the mug's cached samples are reused."""
    mug = _split_mug(split, mug_index)
    candidates = [i for i in pool if i != mug_index]
    views = []
    for view_id in range(views_per_mug):
        rng = np.random.default_rng([seed, mug_index, view_id])
        # As many candidate occluder mugs as there can be occluders: only those get built.
        picked = rng.choice(len(candidates), min(config.occluder_count_range[1], len(candidates)), replace=False)
        others = [_split_mug(split, candidates[i]) for i in picked]
        views.append(render_view(mug, others, rng, config, mug_index=mug_index, view_id=view_id))
    stacked = {
        "points": [v.points for v in views],
        "n_visible": [v.n_visible for v in views],
        "pose_camera_object": [v.pose_camera_object for v in views],
        "center": [v.center_camera for v in views],
        "queries": [v.queries for v in views],
        "occupancy": [v.occupancy for v in views],
        "mug_index": [v.mug_index for v in views],
        "view_id": [v.view_id for v in views],
    }
    return {name: np.asarray(values, dtype=DATASET_ARRAYS[name]) for name, values in stacked.items()}


@functools.lru_cache(maxsize=2048)
def _split_mug(split: str, index: int) -> Mug:
    # Building a mug takes ~7 ms and a worker reuses the same few hundred as occluders.
    return make_split_mug(split, index)


def write_dataset(path: str | Path, dataset: dict[str, np.ndarray]) -> Path:
    """Write `dataset` to `path` as one compressed .npz; a reader never sees a half-written file."""
    path = Path(path)
    with atomic_path(path) as temporary, open(temporary, "wb") as file:  # a file object: np.savez would append ".npz" to a name
        np.savez_compressed(file, **dataset)
    return path


def load_dataset(path: str | Path) -> dict[str, np.ndarray]:
    """The dataset written to `path` by `write_dataset`. DataError, naming the file, if it is
    missing, unreadable, or lacks or mis-shapes any of `DATASET_ARRAYS`."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such dataset file")
    try:
        with np.load(path, allow_pickle=False) as archive:
            dataset = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as error:
        raise DataError(f"{path}: not a readable dataset file ({error})") from error
    _check_dataset(path, dataset)
    return dataset


def _check_dataset(path: Path, dataset: dict[str, np.ndarray]) -> None:
    missing = sorted(set(DATASET_ARRAYS) - set(dataset))
    if missing:
        raise DataError(f"{path}: not a dataset file, it lacks {', '.join(missing)}")
    views = len(dataset["points"])
    points, queries = dataset["points"], dataset["queries"]
    shapes_ok = (
        points.ndim == 3 and points.shape[2] == 3 and queries.ndim == 3 and queries.shape[2] == 3
        and dataset["occupancy"].shape == queries.shape[:2]
        and dataset["pose_camera_object"].shape == (views, 4, 4) and dataset["center"].shape == (views, 3)
        and all(len(dataset[name]) == views for name in DATASET_ARRAYS)
    )
    if not shapes_ok:
        shapes = {name: dataset[name].shape for name in DATASET_ARRAYS}
        raise DataError(f"{path}: dataset arrays have inconsistent shapes {shapes}")


# ----------------------------------------------------------------------------------------------
# Batches


def sample_batch(dataset: dict[str, np.ndarray], n_mugs: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
    """A batch for the batch-hard shape loss: `n_mugs` distinct mugs, two different views of each.

    Returns float32 tensors in the camera frame (the trainer centres them): points [2B, N, 3],
    queries [2B, Q, 3], occupancy [2B, Q] (0/1), center [2B, 3], rotation [2B, 3, 3] (mug frame -> camera), and mug_index [2B] int64; rows
    b and b + B are the two views of the same mug. Only mugs with two or more views are drawn.
    """
    return sample_rows(dataset, batch_rows(dataset, n_mugs, rng))


def sample_rows(dataset: dict[str, np.ndarray], rows: np.ndarray) -> dict[str, torch.Tensor]:
    """The views `rows` of `dataset` as `sample_batch`'s tensors."""
    import torch  # here, so that generation workers do not load torch

    return {
        "points": torch.from_numpy(dataset["points"][rows].astype(np.float32)),
        "queries": torch.from_numpy(dataset["queries"][rows].astype(np.float32)),
        "occupancy": torch.from_numpy(dataset["occupancy"][rows].astype(np.float32)),
        "center": torch.from_numpy(dataset["center"][rows].astype(np.float32)),
        "rotation": torch.from_numpy(dataset["pose_camera_object"][rows, :3, :3].astype(np.float32)),
        "mug_index": torch.from_numpy(dataset["mug_index"][rows].astype(np.int64)),
    }


def batch_rows(dataset: dict[str, np.ndarray], n_mugs: int, rng: np.random.Generator) -> np.ndarray:
    """Rows of `sample_batch`'s views `[2 * n_mugs]`: rows b and b + n_mugs are two views of one mug."""
    order = np.argsort(dataset["mug_index"], kind="stable")  # rows of each mug side by side
    _, starts, counts = np.unique(dataset["mug_index"][order], return_index=True, return_counts=True)
    eligible = np.flatnonzero(counts >= 2)
    if len(eligible) < n_mugs:
        raise DataError(f"a batch of {n_mugs} mugs needs {n_mugs} mugs with two views; the dataset has {len(eligible)}")
    chosen = rng.choice(eligible, size=n_mugs, replace=False)
    first = rng.integers(counts[chosen])
    second = (first + rng.integers(1, counts[chosen])) % counts[chosen]  # never equal to first
    return order[np.concatenate([starts[chosen] + first, starts[chosen] + second])]


# ----------------------------------------------------------------------------------------------
# Shape parameters, for the optional parameter loss


# The MugParams fields that are numbers (metres or fractions), in their order: shape_parameters' first columns.
NUMERIC_PARAMS = [name for name, kind in MugParams.__annotations__.items() if kind == "float"]


def shape_parameters(split: str, mug_indices: list[int]) -> np.ndarray:
    """What makes each mug its shape, as numbers `[len(mug_indices), P]`: every numeric field of
    its `MugParams` (metres or fractions) and one-hot profile, base style and handle shape.

    Regressing these from the shape code (`ndfa train --param-weight`) tells the encoder which
    differences between mugs matter, in units that carry over to mugs it never saw; the identity
    losses only say "this mug, not those". Handle fields of a handle-less mug are zero."""
    rows = []
    for index in mug_indices:
        params = sample_mug_params(np.random.default_rng(mug_seed(split, index)))
        has_handle = params.handle_shape != "none"
        numbers = [getattr(params, name) * (has_handle or not name.startswith("handle_")) for name in NUMERIC_PARAMS]
        tags = [params.profile == p for p in PROFILES] + [params.base_style == b for b in BASE_STYLES]
        rows.append(numbers + tags + [params.handle_shape == h for h in HANDLE_SHAPES])
    return np.asarray(rows, dtype=np.float32)

