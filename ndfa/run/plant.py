"""`ndfa plant`: a pair of recordings with changes planted, to measure ndfa on one's own data.

The I/O shell around `ndfa.sim.plant`: it reads a source and a target recording (with camera poses
in one shared world), works out where each planned object stands (`ndfa.run.plant_plan`: a plan
file, or placements drawn from a seed on the largest support surface both saw), and writes both
as copies into a folder, `source.mcap` and `target.mcap`, with

- a real object marked removed taken out of every target frame (its pixels: the support behind it);
- each mesh put into the frames of the sessions it stands in (ray cast, noisy, z-tested);
- the ground truth of what was planted (/ndfa/ground_truth: objects with their pose in each
  session and their change, which instances each session shows, and the world's levelling), so
  that `ndfa detect source.mcap target.mcap` scores its reports by position.

Positions are in the source's world as `ndfa detect` levels it (`ndfa.run.world.prepare_session`);
the same levelling places the objects in both sessions, so both must share one world (the poses
of one map, e.g. a dataset's). Frames with nothing planted in view are copied as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ndfa.core.conventions import MAX_DEPTH_M, MIN_DEPTH_M, is_visible
from ndfa.core.errors import OptionError, RecordingError
from ndfa.core.frame import Frame
from ndfa.core.geometry import invert_pose, make_pose, rotation_z
from ndfa.core.progress import LabelledProgress
from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.io.recording.ground_truth import REAL_MODEL
from ndfa.perception.segmentation import segment_frame
from ndfa.run.plant_plan import CLEARANCE_M, PlantedObject, auto_plan, load_mesh, mesh_color
from ndfa.run.world import prepare_session
from ndfa.sim.noise import DepthNoise
from ndfa.sim.plant import ColorGrid, Cylinder, MeshInserter, camera_of, remove_object, world_points
from ndfa.sim.plant_place import SAME_OBJECT_M, free_spots, group_centers, largest_plane, support_at
from ndfa.sim.render import RenderObject

SESSIONS = ("source", "target")
CLOUD_FRAMES = 30   # frames per session in the scene cloud (spread over the session)
CLOUD_STRIDE = 4    # every 4th pixel along each axis
SUPPORT_REACH_M = 0.15  # the support under an object: points this far around its region
DISCOVER_FRAMES = 20  # frames per session segmented to find the real objects (--auto without a plan)
RECUR_SHARE = 0.5    # ... an object is found in at least this share of the frames that see its place
OCCLUDED_M = 0.10    # a place is hidden from a frame whose depth there is this much nearer
SINK_M = 0.001      # a mesh stands this far into its support, so no gap shows under it
_WRITER_META_KEYS = ("format", "format_version", "depth_scale", "units")


@dataclass
class PlantResult:
    paths: dict[str, Path]
    objects: list[PlantedObject]
    ground_truth: dict
    frames: dict[str, int] = field(default_factory=dict)
    edited: dict[str, int] = field(default_factory=dict)   # frames with a planted pixel, per session
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class _Placed:
    """A planned object resolved in one session: its region (real) or its render object (mesh)."""

    instance_id: int
    obj: PlantedObject
    region: Cylinder
    pose_level_object: np.ndarray
    render: RenderObject | None


def run_plant(source: Path, target: Path, out_dir: Path, plan: list[PlantedObject], auto_seed: int | None = None,
              log: Path | None = None, preview_every: int = 25, noise: DepthNoise = DepthNoise(),
              color_K: np.ndarray | None = None, color_offset_m: float = 0.0, frame_step: int = 1,
              on_frame: LabelledProgress | None = None) -> PlantResult:
    """Write `out_dir`/source.mcap and target.mcap (see the module docstring). `plan`: the objects;
    with `auto_seed`, its real objects are kept and the seed's placements added (`auto_plan`).
    `color_K`, `color_offset_m`: the colour camera's intrinsics and offset along the depth camera's
    x axis when the colour is not registered to the depth (`ndfa.sim.plant.ColorGrid`); None: it is. `frame_step`: only every n-th frame is written
    (a shorter copy, for `ndfa detect` with every frame of it; pose estimation sees fewer frames)."""
    readers = {"source": RecordingReader(source), "target": RecordingReader(target)}
    paths = {session: Path(out_dir) / f"{session}.mcap" for session in SESSIONS}
    for session, reader in readers.items():
        if len(reader) == 0:
            raise RecordingError(f"{reader.path}: has no frames")
        if not reader.has_poses:
            raise RecordingError(f"{reader.path}: has no camera poses; `ndfa plant` places objects in the world "
                                 "the poses give (estimate them first: `ndfa poses`)")
        if reader.ground_truth and reader.ground_truth.get("objects"):
            raise RecordingError(f"{reader.path}: already has ground-truth objects; plant into a recording without")
        if paths[session].resolve() in (Path(source).resolve(), Path(target).resolve()):
            raise RecordingError(f"{paths[session]}: the output must not be an input recording")
    world = prepare_session(readers["source"], "source", up="auto", poses="given")
    levelling = np.eye(3) if world.levelling is None else world.levelling
    pose_level_world = make_pose(levelling, np.zeros(3))
    clouds = [scene_cloud(readers[s], pose_level_world) for s in SESSIONS]
    notes = [f"world: {world.describe_up()}"]
    if auto_seed is not None:
        if any(not o.real for o in plan):
            raise OptionError("--auto places the meshes itself: a plan given with it may list real objects only")
        if not plan:
            plan = discover_real_objects(readers, pose_level_world)
            notes.append(f"real objects found (segments in most frames seeing their place, in both sessions): "
                         f"{'; '.join(o.describe() for o in plan) or 'none'}")
        found = largest_plane(clouds)
        if found is None:
            raise RecordingError(f"{source}, {target}: no horizontal support surface seen by both")
        spots = free_spots(found[0], clouds, CLEARANCE_M)
        plan = auto_plan(plan, spots, auto_seed)
        notes.append(f"auto (seed {auto_seed}): {len(spots)} free spots on the largest support surface both saw")
    placed = {s: _place(plan, s, np.vstack(clouds)) for s in SESSIONS}
    truth = _ground_truth(plan, placed, invert_pose(pose_level_world))

    preview = None
    if log is not None:
        from ndfa.log.plant_preview import PlantPreview

        preview = PlantPreview(log)
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    writers = {s: RecordingWriter(paths[s], _meta(readers[s], plan, auto_seed)) for s in SESSIONS}
    result = PlantResult(paths, plan, truth, notes=notes)
    visible: dict[str, list[int]] = {}
    try:
        for session in SESSIONS:
            frames, edited, pixels = _plant_session(readers[session], writers[session], placed[session],
                                                    pose_level_world, noise, color_K, color_offset_m, frame_step,
                                                    preview, preview_every, session, on_frame)
            result.frames[session], result.edited[session] = frames, edited
            visible[session] = sorted(i for i, n in pixels.items() if is_visible(n))
        truth["visible"] = visible
        for session in SESSIONS:
            writers[session].write_ground_truth(dict(truth, session=session))
    except BaseException:
        for writer in writers.values():
            writer.abort()
        if preview is not None:
            preview.abort()
        raise
    for writer in writers.values():
        writer.close()
    if preview is not None:
        preview.close()
    for obj_id, obj in enumerate(plan, start=1):
        for session in SESSIONS:
            if obj.xy(session) is not None and obj_id not in visible[session]:
                notes.append(f"{obj.name} is not visible in the {session} (fewer than the pixels that make an "
                             "object visible): it is not scored there")
    return result


def scene_cloud(reader: RecordingReader, pose_level_world: np.ndarray) -> np.ndarray:
    """(N, 3) points of `CLOUD_FRAMES` frames spread over the recording, every `CLOUD_STRIDE`-th
    pixel, in the levelled world."""
    step = max(1, len(reader) // CLOUD_FRAMES)
    points = []
    for frame in reader.frames(step=step):
        camera = camera_of(frame.K, frame.image_size)
        pose = pose_level_world @ frame.pose_world_camera
        depth = frame.depth[::CLOUD_STRIDE, ::CLOUD_STRIDE]
        rays = camera.pixel_rays()[::CLOUD_STRIDE, ::CLOUD_STRIDE]
        valid = (depth > MIN_DEPTH_M) & (depth < MAX_DEPTH_M)
        local = rays[valid] * depth[valid, None]
        points.append(local @ pose[:3, :3].T + pose[:3, 3])
    return np.concatenate(points) if points else np.empty((0, 3))


def discover_real_objects(readers: dict[str, RecordingReader], pose_level_world: np.ndarray) -> list[PlantedObject]:
    """The real objects of a pair: groups of segments (`ndfa.perception.segmentation`, on
    `DISCOVER_FRAMES` frames of each session) found in at least `RECUR_SHARE` of the frames that
    see their place, in each session."""
    views: dict[str, list[tuple[Frame, np.ndarray]]] = {}
    for session, reader in readers.items():
        views[session] = []
        for frame in reader.frames(step=max(1, len(reader) // DISCOVER_FRAMES)):
            level = replace(frame, pose_world_camera=pose_level_world @ frame.pose_world_camera)
            labels = segment_frame(level)
            points = world_points(level.depth, camera_of(level.K, level.image_size), level.pose_world_camera)
            centers = [points[labels == k].mean(axis=0) for k in range(1, int(labels.max()) + 1) if (labels == k).any()]
            views[session].append((level, np.array(centers).reshape(-1, 3)))
    candidates = group_centers(np.vstack([c for frames in views.values() for _, c in frames]))
    found = []
    for center in candidates:
        shares = []
        for frames in views.values():
            seeing = [c for level, c in frames if _sees(level, center)]
            hits = sum(bool(len(c)) and float(np.min(np.linalg.norm(c[:, :2] - center[:2], axis=1))) <= SAME_OBJECT_M
                       for c in seeing)
            shares.append(hits / len(seeing) if seeing else 0.0)
        if min(shares) >= RECUR_SHARE:
            found.append(PlantedObject(f"real object {len(found) + 1}", "unchanged", True, center[:2], center[:2]))
    return found


def _sees(frame: Frame, point: np.ndarray) -> bool:
    """Whether `frame` sees `point` (levelled world): in the image, in range, nothing much nearer."""
    local = invert_pose(frame.pose_world_camera) @ np.append(point, 1.0)
    if not MIN_DEPTH_M < local[2] < MAX_DEPTH_M:
        return False
    u, v = (frame.K @ (local[:3] / local[2]))[:2]
    height, width = frame.image_size
    if not (0 <= round(v) < height and 0 <= round(u) < width):
        return False
    measured = frame.depth[round(v), round(u)]
    return measured == 0 or measured > local[2] - OCCLUDED_M


def _place(plan: list[PlantedObject], session: str, cloud: np.ndarray) -> list[_Placed]:
    """The objects of `plan` standing in `session`, each on the support found under it; in the
    target also the real objects removed from it, where they stood in the source."""
    placed = []
    for instance_id, obj in enumerate(plan, start=1):
        xy = obj.xy(session)
        if xy is None and obj.real and session == "target":
            xy = obj.source_xy  # the region to take out
        if xy is None:
            continue
        mug = None if obj.real else load_mesh(obj.mesh)
        radius = obj.radius_m if mug is None else _footprint(mug.mesh.vertices)
        height = obj.height_m if mug is None else float(mug.mesh.vertices[:, 2].max()) + 0.02
        inner = radius if obj.real else 0.0
        plane = support_at(cloud, xy, inner, radius + SUPPORT_REACH_M)
        if plane is None:
            raise OptionError(f"{obj.name}: no support surface found at ({xy[0]:.2f}, {xy[1]:.2f}) in the "
                              f"{session}'s frames (positions are in the source's levelled world, metres)")
        foot = plane.foot(xy)
        pose = make_pose(rotation_z(np.radians(obj.yaw_deg)), foot - np.array([0.0, 0.0, SINK_M]))
        render = None if mug is None else RenderObject(mug.mesh.transformed(pose), instance_id, mesh_color(obj))
        placed.append(_Placed(instance_id, obj, Cylinder(foot, radius, height, plane), pose, render))
    return placed


def _footprint(vertices: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(vertices[:, :2], axis=1)))


def _plant_session(reader: RecordingReader, writer: RecordingWriter, placed: list[_Placed],
                   pose_level_world: np.ndarray, noise: DepthNoise, color_K: np.ndarray | None, color_offset_m: float,
                   frame_step: int,
                   preview, preview_every: int, session: str, on_frame: LabelledProgress | None
                   ) -> tuple[int, int, dict[int, int]]:
    """Plant `placed` into every frame of `reader`, write them; frames written, frames edited, and
    the pixels each object showed in its fullest view."""
    removed = [p for p in placed if p.obj.real and p.obj.xy(session) is None]
    real = [p for p in placed if p.obj.real and p not in removed]
    inserter = MeshInserter([p.render for p in placed if p.render is not None], noise)
    pixels: dict[int, int] = {}
    total, edited = len(range(0, len(reader), frame_step)), 0
    for count, frame in enumerate(reader.frames(step=frame_step), start=1):
        camera = camera_of(frame.K, frame.image_size)
        grid = None if color_K is None else ColorGrid(frame.K, color_K, color_offset_m)
        pose = pose_level_world @ frame.pose_world_camera
        rng = np.random.default_rng([frame.index, 7 if session == "source" else 11])
        rgb, depth, changed = frame.rgb, frame.depth, np.zeros(frame.image_size, dtype=bool)
        for p in real:
            seen = int(np.count_nonzero((depth > 0) & p.region.contains(world_points(depth, camera, pose))))
            pixels[p.instance_id] = max(pixels.get(p.instance_id, 0), seen)
        for p in removed:  # not in this session: not visible in it
            rgb, depth, hole = remove_object(rgb, depth, camera, pose, p.region, noise, rng, grid)
            changed |= hole
        rgb, depth, shown = inserter.insert(rgb, depth, camera, pose, rng, grid)
        changed |= shown > 0
        ids, counts = np.unique(shown[(shown > 0) & (depth > 0)], return_counts=True)
        for i, n in zip(ids.tolist(), counts.tolist()):
            pixels[i] = max(pixels.get(i, 0), n)
        out = frame
        if changed.any():
            edited += 1
            instances = None if frame.instances is None else np.where(shown > 0, shown, frame.instances)
            out = replace(frame, rgb=rgb, depth=depth, instances=instances)
        writer.write_frame(out)
        if preview is not None and (count - 1) % preview_every == 0:
            preview.log(session, frame.index, (frame.rgb, frame.depth), (out.rgb, out.depth))
        if on_frame is not None:
            on_frame(session, count, total)
    return total, edited, pixels


def _ground_truth(plan: list[PlantedObject], placed: dict[str, list[_Placed]], pose_world_level: np.ndarray) -> dict:
    """The ground-truth message: the objects (pose per session in the recording's world, change),
    the levelling (so that scoring measures horizontal distances), and the plan."""
    objects = []
    for instance_id, obj in enumerate(plan, start=1):
        entry: dict = {"instance_id": instance_id, "model_id": REAL_MODEL if obj.real else obj.mesh, "name": obj.name,
                       "change": obj.change, "partner": None}
        for session in SESSIONS:
            here = next((p for p in placed[session] if p.instance_id == instance_id), None)
            here = None if obj.xy(session) is None else here
            entry[session] = None if here is None else {
                "pose_world_object": (pose_world_level @ here.pose_level_object).tolist(),
                "radius_m": here.region.radius}
        objects.append(entry)
    return {"format": "ndfa.plant", "objects": objects, "changes": _change_counts(plan),
            "world_tilt": {"pose_world_level": pose_world_level.tolist()},
            "planted": [o.as_dict() for o in plan]}


def _change_counts(plan: list[PlantedObject]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for obj in plan:
        if obj.change != "unchanged":
            counts[obj.change] = counts.get(obj.change, 0) + 1
    return counts


def _meta(reader: RecordingReader, plan: list[PlantedObject], seed: int | None) -> dict:
    meta = {k: v for k, v in reader.meta.items() if k not in _WRITER_META_KEYS}
    meta["planted"] = {"from": str(reader.path), "objects": len(plan), "auto_seed": seed}
    return meta

