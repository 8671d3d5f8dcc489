"""Events -> a Rerun recording (.rrd) to open with `rerun out.rrd` or `ndfa view out.rrd`.

Entity layout (world frame: the source's; `target/` is placed into it with T_rel once registered):

    {session}/camera                  pose (Transform3D) + Pinhole; depth, color, instances under it
    {session}/observations/{id}       the cleaned partial cloud and the NDF reconstruction of mask id
    {session}/objects/{object}        object center (labelled) and its shape code (BarChart); under
                                      points/ its fullest view so far (the largest partial cloud of
                                      its measurements, at most OBJECT_POINTS points), so that the
                                      world view shows every object, not only the current frame's
    {session}/tree                    occupied tree cells (l x l boxes) and the interval nodes
    registration                      inlier center pairs, as lines, and the T_rel text
    graphs/{object}                   target object's edges (green: consistent, red: not) and its
                                      shape match's source edges (blue), in the source world
    decisions                         changes as labelled points, and a text log of every decision
    timings/{stage}                   ms per frame
    pose_quality/{session}            estimated poses judged without ground truth: the verdict and
                                      figures as text, the estimated error (cm) as a scalar under it

The file carries its own layout (`detection_blueprint`), so that `rerun out.rrd`, `ndfa view` and
`ndfa view --web` open on the question the run answers: what changed, and where. Labels are drawn
only on the reported changes; every other label (mask ids, object ids, cell counts) is kept in the
data and shown on hover, since a dozen of them on one table pile up into an unreadable smudge.

Timelines: `frame` (the frame index within its session) and `step` (frames processed so far,
source then target), so that each decision sits at the target frame that made it.

Many sessions (`ndfa.run.sessions`): the roots are the sessions' names (`session_0/`, ...), each
placed into the first session's world once its pair registered it; `step` runs on through all of
them, and a `session` timeline numbers them, so the viewer plays the visits in order. At the end,
`history/` holds every object over the sessions (`ndfa.core.sessions.HistoryRow`): at each
`session` its present objects (labelled with their history id, coloured by the pair decision that
explains them), and each object's track through the sessions as a line.

The file is streamed to a hidden temporary beside PATH (`ndfa.io.atomic.Staged`) and moved onto
PATH on close, which the run does also when interrupted: PATH then holds everything up to the
interruption, and is never half-written. `ndfa detect` runs inside `ndfa.io.atomic.all_or_nothing`,
which puts back what PATH was when the run fails or is interrupted. A process killed outright
leaves the readable stream in `.PATH.tmp-*/`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from ndfa.core.events import (
    AssociationEvent,
    DecisionEvent,
    Event,
    FrameEvent,
    GraphEvent,
    ObservationEvent,
    PoseQualityEvent,
    RegistrationEvent,
    TimingEvent,
    TreeEvent,
)
from ndfa.core.sessions import HistoryEvent, PairEvent, SessionStartEvent
from ndfa.io.atomic import Staged

KIND_COLORS = {"added": (230, 60, 60), "removed": (240, 160, 30), "moved": (170, 80, 230), "rotated": (40, 190, 220),
               "unchanged": (90, 200, 90)}
WITHHELD_COLOR = (150, 150, 150)  # a change withheld: its place not shown by the other session
SESSION_COLORS = {"source": (80, 140, 255), "target": (255, 120, 80)}
# Sessions of a many-session run, in order (then again): blue, orange, green, pink, teal, yellow.
SESSION_PALETTE = ((80, 140, 255), (255, 120, 80), (90, 200, 120), (230, 110, 200), (60, 200, 210), (220, 200, 60))
TABLE_HEIGHT_BOX_M = 0.3  # height of the tree-cell boxes drawn around the objects
OBJECT_POINTS = 300  # points kept of an object's fullest view: enough to see a mug, small in the file


def detection_blueprint(places: np.ndarray | None = None,
                        sessions: tuple[str, ...] = tuple(SESSION_COLORS)) -> rrb.Blueprint:
    """The layout a run opens in: the 3-D world large on the left; on the right the camera image
    with its masks (target first: its frames make the decisions), the decisions log, and the
    per-stage timings.

    places: (N, 3) points the world view's eye should take in (the objects and the changes, in the
    source world); without them the viewer fits its eye to what it has drawn when the view opens,
    which in a slowly streaming browser is the first few objects.

    The world view leaves out the cameras (their depth, as back-projected clouds of the whole room,
    buries the objects, and the frustums, metres away, shrink the view the viewer fits to them;
    the image view shows what the camera sees) and everything that is not 3-D; the tree cells are
    there but hidden (the eye icon shows them): as floor-high boxes they cover the objects they group.

    sessions: the sessions' names in order (a camera tab each, the last first)."""
    world = rrb.Spatial3DView(
        name="world (source frame): objects and changes", origin="/",
        contents=["+ /**", *(f"- /{session}/camera/**" for session in sessions),
                  "- /timings/**", "- /decisions/log", "- /registration/log"],
        overrides={f"/{session}/tree/cells": rrb.EntityBehavior(visible=False) for session in sessions},
        eye_controls=None if places is None or not len(places) else eye_on(places))
    cameras = rrb.Tabs(*(rrb.Spatial2DView(name=f"{session} camera: colour and masks", origin=f"/{session}/camera",
                                          contents=["+ $origin/**", "- $origin/depth"])
                         for session in reversed(sessions)))
    decisions = rrb.TextLogView(name="decisions and registration", origin="/",
                                contents=["+ /decisions/log", "+ /registration/log"])
    timings = rrb.TimeSeriesView(name="ms per frame, by stage", origin="/timings")
    return rrb.Blueprint(
        rrb.Horizontal(world, rrb.Vertical(cameras, decisions, timings, row_shares=[3, 2, 2]), column_shares=[2, 1]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="collapsed"))


def eye_on(places: np.ndarray) -> rrb.EyeControls3D:
    """An orbiting eye above and in front of the places' box (z is up, as logged at `/`), far
    enough to take all of it in."""
    low, high = places.min(axis=0), places.max(axis=0)
    center, size = (low + high) / 2, max(float(np.linalg.norm(high - low)), 1.0)
    return rrb.EyeControls3D(kind=rrb.Eye3DKind.Orbital, look_target=center, eye_up=(0.0, 0.0, 1.0),
                             position=center + size * np.array([-0.3, -0.7, 0.65]))


class RerunSink:
    def __init__(self, path: Path, log_images: bool = True) -> None:
        self.path = Path(path)
        self.log_images = log_images
        self.rec = rr.RecordingStream("ndfa_detect")
        self._staged = Staged(self.path)  # makes the folder: `--log out/run.rrd` in a fresh checkout
        self.rec.save(str(self._staged.temporary))
        # Active as well as default: a viewer that remembers an older layout of this app shows this one.
        self.rec.send_blueprint(detection_blueprint(), make_active=True, make_default=True)
        self.rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._step = 0
        self._observation_entities: dict[str, set[str]] = {"source": set(), "target": set()}
        self._frame_clouds: dict[tuple[str, int], np.ndarray] = {}  # this frame's partial cloud per mask id
        self._object_view_size: dict[tuple[str, int], int] = {}  # points in each object's fullest view
        self._places: dict[str, np.ndarray] = {}  # source objects and changes, in the source world: the eye's
        self._sessions: tuple[str, ...] = tuple(SESSION_COLORS)  # names in order; the first is the world's
        self._registered = "target"  # the session an accepted registration places into the first's world

    def log(self, event: Event) -> None:
        handler = getattr(self, "_" + type(event).__name__, None)
        if handler is not None:
            handler(event)

    def close(self) -> None:
        if self._places:
            # The same layout again, its eye now on the whole scene: the viewer takes the last one sent.
            self.rec.send_blueprint(detection_blueprint(np.stack(list(self._places.values())), self._sessions),
                                    make_active=True, make_default=True)
        self.rec.flush()
        self.rec.disconnect()
        self._staged.commit()

    def _color(self, session: str) -> tuple[int, int, int]:
        if session in SESSION_COLORS:
            return SESSION_COLORS[session]
        return SESSION_PALETTE[self._sessions.index(session) % len(SESSION_PALETTE)] \
            if session in self._sessions else (200, 200, 200)

    # -- one method per event type --------------------------------------------------------------

    def _SessionStartEvent(self, e: SessionStartEvent) -> None:
        if e.names != self._sessions:
            self._sessions = e.names
            self.rec.send_blueprint(detection_blueprint(sessions=self._sessions), make_active=True, make_default=True)
        self.rec.set_time("session", sequence=e.index)

    def _PairEvent(self, e: PairEvent) -> None:
        self._registered = e.target

    def _HistoryEvent(self, e: HistoryEvent) -> None:
        tracks: dict[int, list[np.ndarray]] = {}
        for session, _ in enumerate(e.names):
            rows = [r for r in e.rows if r.session == session and r.present and r.center_first is not None]
            self.rec.set_time("session", sequence=session)
            if not rows:
                self.rec.log("history/objects", rr.Clear(recursive=False))
                continue
            self.rec.log("history/objects", rr.Points3D(
                [r.center_first for r in rows], radii=0.015, show_labels=False,
                colors=[KIND_COLORS.get(r.decision or "unchanged", (200, 200, 200)) for r in rows],
                labels=[f"o{r.object} {r.decision or ''}".strip() for r in rows]))
            for r in rows:
                tracks.setdefault(r.object, []).append(r.center_first)
        for obj, centers in tracks.items():
            if len(centers) > 1:
                self.rec.log(f"history/tracks/{obj}", rr.LineStrips3D([np.stack(centers)], colors=(200, 200, 200),
                                                                      labels=[f"o{obj}"], show_labels=False), static=True)

    def _FrameEvent(self, e: FrameEvent) -> None:
        self._step += 1
        self.rec.set_time("step", sequence=self._step)
        self.rec.set_time("frame", sequence=e.frame.index)
        f, root = e.frame, f"{e.session}/camera"
        height, width = f.image_size
        self.rec.log(root, rr.Transform3D(translation=f.pose_world_camera[:3, 3], mat3x3=f.pose_world_camera[:3, :3]))
        self.rec.log(root, rr.Pinhole(image_from_camera=f.K, resolution=[width, height], camera_xyz=rr.ViewCoordinates.RDF,
                                      image_plane_distance=0.3))
        if self.log_images:
            self.rec.log(f"{root}/depth", rr.DepthImage(f.depth, meter=1.0))
            if f.rgb is not None:
                self.rec.log(f"{root}/color", rr.Image(f.rgb))
            if f.instances is not None:
                self.rec.log(f"{root}/instances", rr.SegmentationImage(f.instances))
        # Last frame's observations vanish unless seen again.
        for entity in self._observation_entities.get(e.session, ()):
            self.rec.log(entity, rr.Clear(recursive=True))
        self._observation_entities[e.session] = set()
        self._frame_clouds = {}

    def _ObservationEvent(self, e: ObservationEvent) -> None:
        if e.skipped is not None or e.points_world is None:
            return
        entity = f"{e.session}/observations/{e.instance_id}"
        self._observation_entities[e.session].add(entity)
        self._frame_clouds[e.session, e.instance_id] = e.points_world
        self.rec.log(f"{entity}/partial", rr.Points3D(e.points_world, colors=self._color(e.session), radii=0.002))
        if e.reconstruction_world is not None and len(e.reconstruction_world):
            self.rec.log(f"{entity}/reconstruction", rr.Points3D(e.reconstruction_world, colors=(120, 220, 120), radii=0.003))
        self.rec.log(f"{entity}/center", rr.Points3D([e.center_world], radii=0.006, labels=[f"mask {e.instance_id}"],
                                                           show_labels=False))

    def _AssociationEvent(self, e: AssociationEvent) -> None:
        entity = f"{e.session}/objects/{e.object_id}"
        if e.session == self._sessions[0]:
            self._places[entity] = np.asarray(e.center_world, dtype=float)
        self.rec.log(entity, rr.Points3D([e.center_world], colors=self._color(e.session), radii=0.01,
                                         labels=[f"{e.session[0]}{e.object_id} {e.category}"], show_labels=False))
        self.rec.log(f"{entity}/shape_code", rr.BarChart(np.asarray(e.shape_code, dtype=np.float32)))
        cloud = self._frame_clouds.get((e.session, e.instance_id))
        if cloud is not None and len(cloud) > self._object_view_size.get((e.session, e.object_id), 0):
            self._object_view_size[e.session, e.object_id] = len(cloud)
            every = -(-len(cloud) // OBJECT_POINTS)  # an even thinning: the view keeps its shape
            self.rec.log(f"{entity}/points", rr.Points3D(cloud[::every], colors=self._color(e.session), radii=0.004))

    def _TreeEvent(self, e: TreeEvent) -> None:
        if not e.cells:
            return
        mins, sizes, labels = [], [], []
        for i, j, ids in e.cells:
            (x0, x1), (y0, y1) = e.x_intervals[i], e.y_intervals[j]
            # A column (the paper's tree) sits on the floor, its height only for display; with T_z,
            # one box per T_z node that holds some of the column's objects.
            slabs = [((0.0, TABLE_HEIGHT_BOX_M), ids)] if not e.z_objects else [
                ((z0, z1), shared) for (z0, z1), in_z in zip(e.z_intervals, e.z_objects)
                if (shared := tuple(sorted(set(ids) & set(in_z))))]
            for (z0, z1), objects in slabs:
                mins.append([x0, y0, z0])
                sizes.append([x1 - x0, y1 - y0, z1 - z0])
                labels.append(f"{len(objects)} objects")
        self.rec.log(f"{e.session}/tree/cells", rr.Boxes3D(mins=mins, sizes=sizes, labels=labels,
                                                           colors=self._color(e.session), show_labels=False))

    def _RegistrationEvent(self, e: RegistrationEvent) -> None:
        if e.accepted and e.transform is not None:
            # The target's world frame, placed into the source's: everything under target/ aligns.
            self.rec.log(self._registered, rr.Transform3D(translation=e.transform[:3, 3], mat3x3=e.transform[:3, :3]))
            registered = e.target_centers @ e.transform[:3, :3].T + e.transform[:3, 3]
            self.rec.log("registration/inliers", rr.LineStrips3D(np.stack([registered, e.source_centers], axis=1),
                                                                 colors=(255, 255, 0)))
        self.rec.log("registration/log", rr.TextLog(
            f"frame {e.frame_index}: {e.method} {'accepted' if e.accepted else 'rejected'}, {len(e.inlier_pairs)} inliers of "
            f"{e.n_pairs} shape pairs, residual {e.residual_m * 1e3:.1f} mm" + (f"; {e.evidence}" if e.evidence else ""),
            level="INFO" if e.accepted else "DEBUG"))

    def _GraphEvent(self, e: GraphEvent) -> None:
        entity = f"graphs/{e.target_id}"
        if len(e.target_edges_source):
            colors = [(60, 200, 60) if ok else (220, 60, 60) for *_, ok in e.edges]
            self.rec.log(f"{entity}/target_edges", rr.Arrows3D(origins=np.repeat([e.center_source], len(e.edges), axis=0),
                                                               vectors=e.target_edges_source, colors=colors))
            self.rec.log(f"{entity}/source_edges", rr.Arrows3D(origins=np.repeat([e.partner_center_source], len(e.edges), axis=0),
                                                               vectors=e.source_edges, colors=(80, 140, 255)))
        else:
            self.rec.log(f"{entity}/target_edges", rr.Clear(recursive=False))
            self.rec.log(f"{entity}/source_edges", rr.Clear(recursive=False))
        self.rec.log(f"{entity}/match", rr.LineStrips3D([[e.center_source, e.partner_center_source]],
                                                        colors=(60, 200, 60) if e.consistent else (220, 60, 60)))

    def _DecisionEvent(self, e: DecisionEvent) -> None:
        position = e.center_source if e.center_source is not None else e.center_world
        withheld = "" if e.withheld is None else "withheld "
        if e.kind != "unchanged":
            self._places[f"decisions/{e.session}_{e.object_id}"] = np.asarray(position, dtype=float)
            self.rec.log(f"decisions/{e.session}_{e.object_id}", rr.Points3D(
                [position], colors=WITHHELD_COLOR if withheld else KIND_COLORS[e.kind], radii=0.03,
                labels=[f"{withheld}{e.kind} {e.category} {e.session[0]}{e.object_id} {e.score:.2f}{_turn(e)}"]))
        why = "" if e.withheld is None else f"; withheld, not reported: {e.withheld}"
        why += f" ({e.sightings} sightings)" if e.sightings else ""
        self.rec.log("decisions/log", rr.TextLog(
            f"frame {e.frame_index}: {e.session} object {e.object_id} ({e.category}) {withheld}{e.kind}{_turn(e)} "
            f"(score {e.score:.2f}): {e.reason}{why}",
            level="INFO" if e.kind == "unchanged" or withheld else "WARN"))

    def _PoseQualityEvent(self, e: PoseQualityEvent) -> None:
        self.rec.log(f"pose_quality/{e.session}", rr.TextDocument(e.text), static=True)
        if np.isfinite(e.error_cm):
            self.rec.log(f"pose_quality/{e.session}/estimated_error_cm", rr.Scalars(e.error_cm), static=True)

    def _TimingEvent(self, e: TimingEvent) -> None:
        for stage, ms in e.stage_ms.items():
            self.rec.log(f"timings/{e.session}/{stage}", rr.Scalars(ms))


def _turn(e: DecisionEvent) -> str:
    """A rotation's turn for its label (" +92°"); empty for the other decisions."""
    return "" if e.angle_deg is None else f" {e.angle_deg:+.0f}°"
