"""One training view of the NDF occupancy network: a partial view of a procedural object (a mug,
or an object of another category: `ndfa.sim.categories`), with occupancy labels. "The mug" below
is whatever object the view is of.

The paper's recipe (Sec. III-C, Fig. 3 and V-C): a randomly posed mug stands on a table with 2-4
other objects around it that may hide parts of it; a camera somewhere around the table, 0.2 to
5 m from its edge and a little above its top, looks at the mug. The depth pixels that the
segmentation assigns to the mug, back-projected, are the partial point cloud the network sees;
the labels are the occupancy of the full mug at query points around it.

One view (`View`); every array is in the CAMERA frame (OpenCV: x right, y down, z forward), metres:
- points (n_points, 3): the mug's visible depth points, with sensor noise, resampled to exactly
  n_points (`n_visible` says how many there were);
- queries (n_queries, 3) and occupancy (n_queries,): half near the mug's surface, half uniform in
  its enlarged bounding box, labelled exactly by `PartsSolid.occupancy`;
- center_camera (3,): the true center of the full mug (`ndfa.training.object_samples.object_center`);
- pose_camera_object (4, 4): mug frame -> camera frame.

Speed: only the target mug's pixels are rendered. Rays are cast through a camera cropped to the
projection of the mug's bounding box (same pose and focal lengths, shifted principal point), and
per-mug work (surface samples, center) is cached: one core makes about 70 views per second.

Determinism: `render_view` draws everything from the generator it is given, in a fixed order;
`ndfa.training.dataset` gives each view its own.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np

from ndfa.core.errors import DataError
from ndfa.core.geometry import (
    invert_pose,
    look_at,
    make_pose,
    rotation_z,
    transform_points,
)
from ndfa.sim.camera import PinholeCamera
from ndfa.sim.mesh import Mesh, box_mesh
from ndfa.sim.mug_body import revolve_profile
from ndfa.sim.noise import DepthNoise
from ndfa.sim.render import RenderObject, SceneRenderer
from ndfa.sim.scene import Table
from ndfa.sim.sensor_artifacts import SensorArtifacts
from ndfa.sim.solid import PartsSolid
from ndfa.training.object_samples import ObjectSamples, object_samples

TARGET_ID = 1  # instance id of the target mug in the rendered instance image; occluders get 2, 3, ...
# Box and cylinder occluders have a mug's size: full extents in metres.
PRIMITIVE_HEIGHT_M = (0.05, 0.15)
BOX_SIDE_M = (0.04, 0.12)
CYLINDER_RADIUS_M = (0.025, 0.06)


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
    occluder_mug_probability: chance that an occluder is one of the other objects given (a mug, or
        any category's object) rather than a box or a cylinder.
    occluder_gap_range_m: free space between the footprint circles of the mug and an occluder.
    noise: the depth sensor model.
    artifacts: a real sensor's artifacts on top of the noise (`ndfa.sim.sensor_artifacts`:
        holes, missing thin handles, flying pixels, quantisation, misregistered masks); None: off.
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
    artifacts: SensorArtifacts | None = None
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
    center_camera: np.ndarray       # (3,) centroid of the mug's solid volume (`object_center`)
    queries: np.ndarray             # (n_queries, 3) near-surface half first, then the uniform half
    occupancy: np.ndarray           # (n_queries,) whether each query is inside the mug
    object_index: int = -1          # index of the object within its category's split (-1: not given)
    view_id: int = -1               # view number of that mug (-1: not given)


def render_view(mug: PartsSolid, others: list[PartsSolid], rng: np.random.Generator, config: ViewConfig = ViewConfig(),
                *, object_index: int = -1, view_id: int = -1) -> View:
    """A partial view of `mug` on a table among occluders, with labels (see the module doc).

    others: objects that may stand around it as occluders (may be empty: boxes and cylinders only).
    rng: the only source of randomness. object_index, view_id: copied into the view.
    Raises DataError if `config.max_attempts` scenes in a row show the mug with too few points.
    """
    samples = object_samples(mug)
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
        visible = _visible_points(SceneRenderer(objects), crop, pose_world_camera, rng, config.noise, config.artifacts,
                                  float(np.max(samples.box_max - samples.box_min)))
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
        object_index=object_index,
        view_id=view_id,
    )


def _place_objects(mug: PartsSolid, others: list[PartsSolid], rng: np.random.Generator,
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


def _occluder_mesh(others: list[PartsSolid], rng: np.random.Generator, config: ViewConfig) -> Mesh:
    """One of `others`, or a box or a cylinder of a mug's size; in its own frame, base at z = 0."""
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
                    rng: np.random.Generator, noise: DepthNoise, artifacts: SensorArtifacts | None = None,
                    object_size_m: float = 0.0) -> np.ndarray:
    """(M, 3) float64 noisy depth points of the target mug (largest extent `object_size_m`), camera frame."""
    rendered = renderer.render(camera, pose_world_camera)
    mask = rendered.instance == TARGET_ID
    if artifacts is None:
        depth = noise.apply(rendered.depth, rendered.normals_camera, rng, camera)
    else:
        depth = artifacts.noise_for_view(noise, rng).apply(rendered.depth, rendered.normals_camera, rng, camera)
        cos_incidence = np.abs(camera.ray_cosines(rendered.normals_camera))
        depth, mask = artifacts.apply(depth, rendered.depth, mask, cos_incidence, rng, object_size_m)
    points, pixels = camera.backproject(depth)
    return points[mask[pixels[:, 0], pixels[:, 1]]]


def _query_points(samples: ObjectSamples, rng: np.random.Generator, config: ViewConfig) -> np.ndarray:
    """(n_queries, 3) query points in the mug frame: near the surface first, then uniform in the box."""
    n_near = config.n_queries // 2
    sigmas = np.resize(np.asarray(config.near_surface_sigmas_m), n_near)  # equal shares, in turn
    near = samples.surface[rng.integers(len(samples.surface), size=n_near)]
    near = near + rng.standard_normal((n_near, 3)) * sigmas[:, None]
    center = (samples.box_min + samples.box_max) / 2
    half = (samples.box_max - samples.box_min) / 2 * (1 + config.box_padding)
    uniform = rng.uniform(center - half, center + half, size=(config.n_queries - n_near, 3))
    return np.concatenate([near, uniform])
