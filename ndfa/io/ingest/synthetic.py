"""`ndfa ingest sim`: render a synthetic source/target pair (or N sessions) into recordings.

The world (`ndfa.sim.world`) says where every mug stands in each session; this module moves the
camera along each session's route, renders depth, instance ids and colour, adds sensor noise,
perturbs the target's poses, and writes `source.mcap` and `target.mcap` with the full ground truth,
including which instances each session shows (`visible`, counted on the rendered masks: a raw
recording has none left to count them on).

With N > 2 sessions (`ndfa.sim.sessions`) it writes `session_0.mcap` ... `session_{N-1}.mcap`:
session 0 along the source route, every later one along the target route with a pose error of its
own. Each recording's ground truth is that of the pair that leads to it (session 0: of the first
pair), as a two-session recording's is, plus `sessions`: every mug's placement in every session
and the change it underwent in each pair (`ndfa.eval.history` scores a run's history against it).

Options that make the recordings closer to raw sensor data (`SimConfig`; all off by default):
textured walls, floor and tables; clutter on the tables; `raw` recordings without instance masks
and camera poses (the true poses stay in the ground-truth pose channel for scoring); and a world
frame tilted away from z-up. The scene is always rendered in the level world; the tilt only
re-expresses what is recorded (camera poses, given and true, and the ground-truth object poses).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

import ndfa
from ndfa.core.conventions import depth_in_range, is_visible
from ndfa.core.errors import IngestError
from ndfa.core.progress import LabelledProgress
from ndfa.io.recording import Frame, RecordingWriter
from ndfa.io.recording.channels import DEPTH_SCALE_M
from ndfa.io.recording.writer import depth_to_millimetres
from ndfa.sim.aligned_depth import AlignedDepth
from ndfa.sim.mug import Mug
from ndfa.sim.office import OfficeFixtures, office_fixtures
from ndfa.sim.presets import SimConfig
from ndfa.sim.render import RenderObject, SceneRenderer
from ndfa.sim.sessions import build_sessions, history_truth, session_names
from ndfa.sim.shelves import shelf_camera_poses
from ndfa.sim.texture import RoomTextures, room_textures
from ndfa.sim.trajectory import camera_poses
from ndfa.sim.world import World, model_category, procedural_models
from ndfa.sim.world_tilt import tilt_pose

# Sessions start on fixed, distinct days so that the two recordings read as two traversals.
SESSION_START = {
    "source": datetime(2026, 1, 5, 9, 0, tzinfo=timezone.utc).timestamp(),
    "target": datetime(2026, 1, 6, 9, 0, tzinfo=timezone.utc).timestamp(),
}



@dataclass(frozen=True)
class SessionSummary:
    session: str
    path: Path
    frames: int
    objects: int
    changes: dict[str, int]
    size_bytes: int


def ingest_sim(
    config: SimConfig,
    out_dir: Path,
    models: list[Mug] | None = None,
    on_progress: LabelledProgress | None = None,  # (session, frames done, frames in session)
    sessions: int = 2,
) -> list[SessionSummary]:
    """Render the sessions of `config` into `out_dir`: `source.mcap` and `target.mcap`, or with
    `sessions` > 2 `session_0.mcap` ... (`ndfa.sim.sessions`: changes between each consecutive pair).

    `models` replaces the procedural test-split mugs (e.g. meshes from `--mesh-dir`).
    """
    out_dir = Path(out_dir)
    check_output_dir(out_dir)
    worlds = build_sessions(config, models if models is not None else procedural_models(config), sessions)
    names = session_names(sessions)
    # The room's look is part of the static scene: one set of textures for every session.
    world = worlds.base
    textures = room_textures(world.room, world.tables, np.random.default_rng([config.seed, 14])) if config.textures else None
    fixtures = office(config, world)
    visible: dict[str, list[int]] = {}  # filled session by session: each recording's ground truth holds those so far
    history = None if sessions == 2 else {"names": names, "objects": history_truth(worlds, world_tilt(config))}
    summaries = []
    for index, name in enumerate(names):
        # A session is the target of the pair that leads to it (the first: the source of the first pair).
        pair = max(index - 1, 0)
        plan = SessionPlan(name, index, worlds.pair(pair), "source" if index == 0 else "target",
                           {"source": names[pair], "target": names[pair + 1]}, history)
        ground_truth = world_ground_truth(plan.world, config)
        summaries.append(_render_session(plan, config, out_dir / f"{name}.mcap", ground_truth, on_progress,
                                         textures, visible, fixtures))
    return summaries


@dataclass(frozen=True)
class SessionPlan:
    """One session to render: its name and place in the order, the two-session world of the pair
    it belongs to and its role there (the source: the first session; the target: every later
    one, whose poses get the pose error), the sessions of that pair (for the ground truth's
    `visible`), and with more than two sessions every mug's history (`ndfa.sim.sessions.history_truth`)."""

    name: str
    index: int
    world: World
    role: str
    pair_names: dict[str, str]
    history: dict | None = None

    @property
    def route_of(self) -> str:
        return "source_route" if self.role == "source" else "target_route"

    @property
    def start(self) -> float:
        """The first frame's timestamp: a day after the session before."""
        return SESSION_START[self.role] + max(self.index - 1, 0) * 86400.0

    def pose_error_rng(self, seed: int) -> np.random.Generator:
        return np.random.default_rng([seed, 11] if self.index <= 1 else [seed, 11, self.index])


def office(config: SimConfig, world: World) -> OfficeFixtures | None:
    """The office's monitors and ceiling (`ndfa.sim.office`), when `config` has any."""
    if not (config.monitors_per_table or config.ceiling):
        return None
    return office_fixtures(world.tables, config.monitors_per_table, config.ceiling,
                           np.random.default_rng([config.seed, 15]))


def world_tilt(config: SimConfig) -> np.ndarray:
    """pose_world_level of `config`'s recordings: the identity unless `world_tilt_deg` is set."""
    return tilt_pose(config.world_tilt_deg, np.random.default_rng([config.seed, 13]))


def _render_session(plan: SessionPlan, config: SimConfig, path: Path, ground_truth: dict,
                    on_progress: LabelledProgress | None, textures: RoomTextures | None = None,
                    visible: dict[str, list[int]] | None = None,
                    fixtures: OfficeFixtures | None = None) -> SessionSummary:
    """Render one session into `path`. `visible` (session name -> instance ids) gains this
    session's visible instances, and the recording's ground truth holds those of its pair rendered
    so far (and with more than two sessions, of every session rendered so far)."""
    session, world = plan.name, plan.world
    # One stream per session and purpose: changing the noise model does not move the cameras.
    stream = plan.index
    route = getattr(config, plan.route_of)
    trajectory, route_rng = dataclasses.replace(config.trajectory, route=route), np.random.default_rng([config.seed, 10, stream])
    true_poses = camera_poses(world.tables, trajectory, route_rng, config.fps) if not world.shelf_units else \
        shelf_camera_poses(world.shelf_units, route, trajectory, route_rng, config.fps)
    recorded_poses, offset = true_poses, None
    if plan.role == "target" and config.target_pose_error.enabled and not config.raw:
        recorded_poses, offset = config.target_pose_error.apply(true_poses, plan.pose_error_rng(config.seed))
    noise_rng = np.random.default_rng([config.seed, 12, stream])
    # Rendered in the level world; recorded in the (possibly) tilted one.
    pose_world_level = world_tilt(config)
    recorded_poses_world = pose_world_level @ recorded_poses
    true_poses_world = pose_world_level @ true_poses
    if offset is not None:  # perturbed = offset @ drift @ true holds in the tilted world with this offset
        offset = pose_world_level @ offset @ pose_world_level.T

    renderer = SceneRenderer(render_objects(world, plan.role, textures, fixtures))
    screen_rng = np.random.default_rng([config.seed, 16, stream])
    if config.raw:
        # What a sensor writes: no poses (the writer then leaves /tf out) and no instance masks.
        poses_meta, instances_meta = "none", "none"
    else:
        poses_meta, instances_meta = "perturbed" if offset is not None else "true", "rendered"
    meta = {
        "source": "sim",
        "session": session,
        "preset": config.preset,
        "seed": config.seed,
        "route": route,
        "frame_rate_hz": config.fps,
        "poses": poses_meta,
        "instances": instances_meta,
        "generator": f"ndfa {ndfa.__version__} ingest sim",
        "config": dataclasses.asdict(config),
    }
    if plan.history is not None:
        meta["sessions"] = {"index": plan.index, "names": plan.history["names"]}
    visible = {} if visible is None else visible
    pixels_seen: dict[int, int] = {}  # instance id -> its most pixels with depth in range in one frame
    camera = config.camera
    with RecordingWriter(path, meta) as writer:
        for index, pose in enumerate(true_poses):
            view = renderer.render(camera, pose)
            depth = config.depth_noise.apply(view.depth, view.normals_camera, noise_rng, camera)
            instance = view.instance
            if fixtures is not None:  # what the sensor reads on the screens; screens are not objects
                depth, instance = fixtures.sensor(depth, instance, screen_rng)
            if config.aligned_depth:
                depth = AlignedDepth().apply(depth, camera.fx)
            for instance_id, n_pixels in visible_pixels(instance, depth).items():
                pixels_seen[instance_id] = max(n_pixels, pixels_seen.get(instance_id, 0))
            writer.write_frame(Frame(
                index=index,
                timestamp=plan.start + index / config.fps,
                rgb=view.rgb,
                depth=depth,
                K=camera.K,
                # A raw recording's frames carry the identity, the recording has no poses.
                pose_world_camera=np.eye(4) if config.raw else recorded_poses_world[index],
                instances=None if config.raw else instance,
                pose_world_camera_true=true_poses_world[index] if offset is not None or config.raw else None,
            ))
            if on_progress is not None:
                on_progress(session, index + 1, len(true_poses))
        # Known once every frame is rendered; the writer stores the ground truth at the end anyway.
        visible[session] = sorted(i for i, n in pixels_seen.items() if is_visible(n))
        truth = dict(ground_truth, session=session, pose_offset=None if offset is None else offset.tolist(),
                     visible={role: visible[name] for role, name in plan.pair_names.items() if name in visible})
        if plan.history is not None:
            # Every mug over every session, and what each session rendered so far showed of them.
            truth["sessions"] = {"names": plan.history["names"], "index": plan.index,
                                 "objects": plan.history["objects"], "visible": dict(visible)}
        writer.write_ground_truth(truth)
    layout = world.layout(plan.role)
    if plan.history is None:
        changes = {kind: n for kind, n in world.change_counts().items()
                   if kind != ("added" if plan.role == "source" else "removed")}
    else:  # the changes since the session before
        changes = {} if plan.index == 0 else world.change_counts()
    return SessionSummary(session, path, len(true_poses), len(layout), changes, path.stat().st_size)


def visible_pixels(instance: np.ndarray, depth: np.ndarray) -> dict[int, int]:
    """Instance id (mugs and clutter) -> its mask pixels with depth in range in one frame, counted on
    the depth as a reader gets it back (millimetres), so that the ground truth's `visible` is what
    the masks of the same recording would give `ndfa.core.conventions.is_visible`: a raw recording has
    no masks to count later."""
    recorded = (depth_to_millimetres(depth) * DEPTH_SCALE_M).astype(np.float32)
    ids = instance[(instance > 0) & depth_in_range(recorded)]
    counts = np.bincount(ids.astype(np.intp))
    return {int(i): int(counts[i]) for i in np.flatnonzero(counts)}


def render_objects(world: World, session: str, textures: RoomTextures | None = None,
                   fixtures: OfficeFixtures | None = None) -> list[RenderObject]:
    """Room, tables, furniture, the session's mugs, the clutter and an office's fixtures as renderable objects
    (level world frame); mugs, clutter and screens carry their instance ids, room and tables the
    `textures` if given."""
    gray, wood = (0.75, 0.75, 0.72), (0.55, 0.40, 0.28)
    room_textures_ = textures.room if textures is not None else [None] * len(world.room.meshes())
    table_textures = textures.tables if textures is not None else [None] * len(world.tables)
    objects = [RenderObject(mesh, 0, gray, texture) for mesh, texture in zip(world.room.meshes(), room_textures_)]
    objects += [RenderObject(table.mesh(), 0, wood, texture) for table, texture in zip(world.tables, table_textures)]
    objects += [RenderObject(piece.mesh, 0, piece.color) for piece in world.furniture]
    objects += [RenderObject(chair.mesh, 0, chair.color) for chair in world.chairs]
    objects += [RenderObject(unit.mesh(), 0, wood) for unit in world.shelf_units]
    for instance_id, placement in world.layout(session).items():
        mesh = world.mugs[placement.model_id].mesh.transformed(world.object_pose(placement))
        objects.append(RenderObject(mesh, instance_id, world.colors[instance_id]))
    for item in world.clutter:
        objects.append(RenderObject(item.mesh.transformed(world.clutter_pose(item)), item.instance_id, item.color))
    if fixtures is not None:
        objects += [RenderObject(mesh, instance_id, colour) for mesh, instance_id, colour
                    in fixtures.render_parts(world.tables, world.room)]
    return objects


def world_ground_truth(world: World, config: SimConfig) -> dict:
    """The scene as JSON-ready data: tables, models, every instance in each session, change labels;
    with the options on, the categories, the clutter and the world tilt.

    Object poses are in the recorded world frame (tilted, with `world_tilt_deg`); the room and the
    tables are described in the level world, which `world_tilt.pose_world_level` maps into it."""
    change_of = {c.instance_id: c for c in world.changes}
    pose_world_level = world_tilt(config)
    # Each object's and model's category, beside mugs; a mugs-only scene's ground truth stays as it
    # was (read as mugs: `ndfa.eval.scoring.instance_categories`).
    categories = config.categories != ("mug",)

    def where(session: str, instance_id: int) -> dict | None:
        placement = world.layout(session).get(instance_id)
        if placement is None:
            return None
        return {"table_id": placement.table_id, "pose_world_object": (pose_world_level @ world.object_pose(placement)).tolist()}

    objects = []
    for instance_id in sorted(world.source.keys() | world.target.keys()):
        placement = world.source.get(instance_id) or world.target[instance_id]
        change = change_of.get(instance_id)
        objects.append({
            "instance_id": instance_id,
            "model_id": placement.model_id,
            **({"category": model_category(world.mugs[placement.model_id])} if categories else {}),
            "source": where("source", instance_id),
            "target": where("target", instance_id),
            "change": change.kind if change else "unchanged",
            "partner": change.partner if change else None,
            **({"angle_deg": change.angle_deg} if change and change.angle_deg is not None else {}),
        })
    counts = world.change_counts()
    truth = {
        "format": "ndfa.ground_truth/1",
        "preset": config.preset,
        "seed": config.seed,
        "room": {"size_xy": list(world.room.size_xy), "wall_height": world.room.wall_height},
        "tables": [dataclasses.asdict(t) for t in world.tables],
        "models": [{"model_id": m.model_id, **({"category": model_category(m)} if categories else {}), "seed": m.seed,
                    "watertight": m.watertight} for m in world.mugs.values()],
        "objects": objects,
        "changes": dict(counts, total=sum(counts.values())),
    }
    # Only with the options on, so that a default scene's ground truth stays as it was.
    if config.clutter_per_table:
        # Static, in both sessions: never a change; objects of a category, and non-objects.
        truth["clutter"] = [{
            "instance_id": item.instance_id,
            "kind": item.kind,
            "category": item.category,  # None: not an object (paper, a cable)
            "table_id": item.table_id,
            "pose_world_object": (pose_world_level @ world.clutter_pose(item)).tolist(),
        } for item in world.clutter]
    if world.shelf_units:  # their levels are the "tables", in the level world
        truth["shelf_units"] = [unit.as_dict() for unit in world.shelf_units]
    if world.furniture:  # part of the room, in the level world
        truth["furniture"] = [piece.as_dict() for piece in world.furniture]
    if world.chairs:  # part of the room
        truth["chairs"] = [chair.as_dict() for chair in world.chairs]
    fixtures = office(config, world)
    if fixtures is not None:  # fixed in every session; not objects
        truth["office"] = {"ceiling": fixtures.ceiling, "monitors": [
            {"table_id": m.table_id, "x": m.x, "screen": m.reading} for m in fixtures.monitors]}
    if config.world_tilt_deg:
        truth["world_tilt"] = {
            "degrees": config.world_tilt_deg,
            "pose_world_level": pose_world_level.tolist(),
            "up_world": pose_world_level[:3, 2].tolist(),
        }
    return truth


def check_output_dir(out_dir: Path) -> None:
    """Fail early, before rendering for minutes, when `out_dir` cannot be written."""
    probe = Path(out_dir) / ".ndfa-write-test"
    try:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        probe.touch()
        probe.unlink()
    except OSError as error:
        raise IngestError(f"cannot write to output directory {out_dir}: {error.strerror or error}") from None
