"""The online change detector (paper Sec. IV): object maps of both sessions, registration, decisions.

Read it top to bottom as the paper's loop:

    source pass   add_source(frame measurements, sightings): intra-session update of the source map
    target pass   add_target(frame measurements, sightings):
                    1. intra-session update of the target map with each -> the objects O touched;
                       the frame's sightings counted on the objects they fall on (`ndfa.change.sightings`)
                    2. T_rel: estimated from shape-matched pairs when it is time to (`Registrar`)
                    3. for each O not marked changed: the change test (`ndfa.change.verdict`) at
                       T_rel t_O; the policy (`ndfa.change.policy`) says whether its verdict is
                       acted on now or O waits; "changed" is reported now, never retracted
    end           finish()       waiting objects decided with the evidence there is; removed =
                                 source objects observed but never matched; a changed target
                                 object that matches a removed one by shape is reported as moved;
                                 an unchanged one whose handle turned about up, as rotated
                                 (`ndfa.change.rotation`; beyond the paper); a changed one standing
                                 where a source object stood, unless the two were seen from no
                                 common side (`ndfa.change.sides`; beyond the paper)

An "added" or "removed" change also needs the other session's frames to have shown its place
(`add_view`, `ndfa.change.sight`; beyond the paper): where they did not, the change is decided
with the reason in `DecisionEvent.withheld` and not reported, nor paired into a move.

Every decision carries a score in [0, 1] (`DecisionEvent.score`; `ndfa.change.verdict.decision_score`,
`removal_score`): changes at least 0.5, "unchanged" below, so a threshold on it trades precision
against recall without changing what the detector does at 0.5 (docs/scores.md).

Pure numpy; every step returns events (`ndfa.core.events`) for the sinks. The parameters and why
they differ from the paper's: `ndfa.change.config`, `docs/detector.md`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ndfa.change.associate import Association, Measurement, SessionMap, SessionObject, cosine_similarity
from ndfa.change.config import DetectorConfig
from ndfa.change.describe import graph_event, tree_event
from ndfa.change.graph import local_graph
from ndfa.change.policy import DecisionPolicy
from ndfa.change.register import Registration, RegistrationPrior, apply
from ndfa.change.registrar import Registrar
from ndfa.change.rotation import rotation_of
from ndfa.change.sides import common_side, mean_azimuth_deg, view_azimuths
from ndfa.change.sight import SessionViews, Sight, SightRule, own_size
from ndfa.change.sightings import SessionSightings, Sighting
from ndfa.change.verdict import Verdict, decision_score, graph_verdict, removal_score, shape_verdict
from ndfa.core.conventions import UNKNOWN_CATEGORY, UP_AXIS, horizontal
from ndfa.core.events import SESSIONS, AssociationEvent, DecisionEvent, DecisionKind, Event, Session
from ndfa.core.geometry import invert_pose

__all__ = ["ChangeDetector", "DetectorConfig", "reported_changes"]


class ChangeDetector:
    def __init__(self, config: DetectorConfig = DetectorConfig(), sight: SightRule = SightRule()) -> None:
        """`sight`: perception's bar for taking an object from a view (the pipeline fills it from its
        `ObservationConfig`), which a change's place must have reached in the other session's frames."""
        self.config = config
        self.views = {session: SessionViews(sight) for session in SESSIONS}  # what each session's frames showed
        self.unseen: dict[int, DecisionEvent] = {}  # target object -> its "added", withheld (place not shown)
        self.source = SessionMap(config)
        self.target = SessionMap(config)
        self.registrar = Registrar(config, self.source, self.target)
        self.policy = DecisionPolicy(config.waiting)
        self.sightings = {session: SessionSightings(config) for session in SESSIONS}  # views too small to encode
        self.changed: dict[int, DecisionEvent] = {}  # target object -> the decision that marked it
        # source object -> the target objects tested around it (its keys: the source objects observed)
        self.observers: dict[int, set[int]] = {}
        # target object -> the source object its latest test found it consistent with; dropped when a
        # later test (more views) finds it changed: the source object was then never matched by it
        self.partners: dict[int, int] = {}
        # target object found changed at the end with a source object standing in its place -> that
        # source object: its decision is made in `finish`, once the removals and moves are known
        self.in_place_of: dict[int, int] = {}
        self._last_frame = -1

    @property
    def registration(self) -> Registration | None:
        """T_rel (target world -> source world), once one is accepted."""
        return self.registrar.registration

    def add_registration_prior(self, prior: RegistrationPrior) -> None:
        """A T_rel hypothesis from outside the object maps (`ndfa.change.registrar`); before the target pass."""
        self.registrar.add_prior(prior)

    # -- the two passes -------------------------------------------------------------------------

    def add_view(self, session: Session, frame_index: int, depth: np.ndarray, K: np.ndarray,
                 pose_world_camera: np.ndarray) -> None:
        """A frame of `session` the detector takes measurements from: what it showed (depth in
        metres, camera -> world pose), for the test that a change's place was shown (`sight`).
        A detector given no views of a session takes every place as shown by it (a replay)."""
        if self.config.evidence.sight_radius_m > 0:
            self.views[session].add(frame_index, depth, K, pose_world_camera)

    def sight(self, session: Session, place_world: np.ndarray, size: float = 1.0,
              reach_m: tuple[float, float] = (np.inf, np.inf)) -> Sight:
        """How well `session`'s frames showed an object of the category standing at `place_world`
        (that session's world): `ndfa.change.sight`, sized by `EvidenceConfig.sight_*` (and
        `size`: `_own_size`), the object standing `reach_m[0]` under its center and reaching
        `reach_m[1]` above it (`_reach`)."""
        evidence = self.config.evidence
        height = float(np.asarray(place_world)[UP_AXIS])
        return self.views[session].sight(place_world, evidence.sight_radius_m, evidence.sight_height_m, size,
                                         height - reach_m[0], height + reach_m[1])

    def _own_size(self, session: Session, obj: SessionObject) -> float:
        """The claimed object's size as its own views (`session`'s) show it, as a share of
        `EvidenceConfig.sight_typical_m`'s cylinder, at most 1 (`ndfa.change.sight.own_size`): 1
        when the rule is off or its cameras are not known (a replay)."""
        typical, views = self.config.evidence.sight_typical_m, self.views[session]
        cameras = views.cameras(obj.frames)
        if typical is None or cameras is None or views.K is None:
            return 1.0
        return own_size(np.asarray(obj.pixels), cameras, obj.center_world, views.K, *typical)

    @staticmethod
    def _reach(obj: SessionObject) -> tuple[float, float]:
        """How far under its center the object stands and how far above it it reaches (its views'
        lowest and highest points: `base_height`, `top_height`; inf when not known): heights that
        hold in either session's world."""
        center = float(obj.center_world[UP_AXIS])
        return (center - obj.base_height if np.isfinite(obj.base_height) else np.inf,
                obj.top_height - center if np.isfinite(obj.top_height) else np.inf)

    def _unshown(self, session: Session, place_world: np.ndarray, size: float = 1.0,
                 reach_m: tuple[float, float] = (np.inf, np.inf)) -> str | None:
        """Why a change at `place_world` is withheld: `session`, the other one, did not show the
        place, or sighted something there that none of its objects is (`WaitingConfig.sightings`,
        `ndfa.change.sightings`), or showed it but not empty while its map holds no object there
        that stood in it (`EvidenceConfig.seen_empty`); None when it saw the place empty, or the
        test is off (`EvidenceConfig.sight_radius_m` 0)."""
        evidence = self.config.evidence
        if evidence.sight_radius_m <= 0:
            return None
        seen = self.sight(session, place_world, size, reach_m)
        if not seen.shown:
            return f"its place was {seen.describe(session)}"
        if self.config.waiting.sightings:  # something too small to encode stood there (`ndfa.change.sightings`)
            session_map = self._map(session)
            sighted = self.sightings[session].unexplained(place_world, session_map)
            if sighted >= self.config.waiting.min_measurements:
                return (f"its place was not seen empty: the {session} sighted something there in {sighted} "
                        "views too small to encode, and none of its objects stood there")
        glimpsed = self._glimpsed_at(session, place_world) if evidence.glimpse_views else None
        if evidence.seen_empty and glimpsed is not None:
            object_id, glimpse = glimpsed
            return (f"its place held {session} object {object_id}, seen {glimpse.n_measurements} time(s): "
                    "too few to test, and no sign that it was not the same object")
        if not evidence.seen_empty or seen.seen_empty or self._stands_at(session, place_world):
            return None
        return f"its place was {seen.describe_occupied(session)}"

    def _glimpsed_at(self, session: Session, place_world: np.ndarray) -> tuple[int, SessionObject] | None:
        """The object of `session`'s map standing in the place (its center within `sight_radius_m`
        horizontally and `sight_height_m` in height) measured at least `EvidenceConfig.glimpse_views`
        times but too few to be tested (`DecisionPolicy.testable`), if any (docs/detector.md)."""
        evidence = self.config.evidence
        session_map = self._map(session)
        return next(((object_id, o) for object_id, o in sorted(session_map.objects.items())
                     if np.linalg.norm(horizontal(o.center_world - place_world)) <= evidence.sight_radius_m
                     and abs(o.center_world[2] - place_world[2]) <= evidence.sight_height_m
                     and o.n_measurements >= evidence.glimpse_views
                     and not self.policy.testable(o.n_measurements, self.sightings[session].count(object_id))), None)

    def _map(self, session: Session) -> SessionMap:
        return self.source if session == "source" else self.target

    def _stands_at(self, session: Session, place_world: np.ndarray) -> bool:
        """Whether `session`'s map holds an object standing in the place (its center within two
        `sight_radius_m` horizontally and `sight_height_m` in height: two such objects would touch):
        what the depth ended on there is then that object, and a change claimed against it (a
        different object there: a switch) stands. For a removal (`session` "target") that object must
        be new there: not matched unchanged to a source object (then the source held that one object
        twice), its own addition not withheld. Only an object the detector would test counts
        (`DecisionPolicy.testable`: `waiting.min_measurements` views): one or two odd views there
        (of a monitor's post, say) are something perception glimpsed, no object a switch could be
        claimed against."""
        evidence = self.config.evidence
        session_map = self._map(session)
        settled = set(self.partners) | set(self.unseen) if session == "target" else set()
        return any(np.linalg.norm(horizontal(o.center_world - place_world)) <= 2 * evidence.sight_radius_m
                   and abs(o.center_world[2] - place_world[2]) <= evidence.sight_height_m
                   and self.policy.testable(o.n_measurements, self.sightings[session].count(object_id))
                   and object_id not in settled
                   for object_id, o in session_map.objects.items())

    def add_source(self, frame: list[Measurement], sightings: list[Sighting] | None = None) -> list[Event]:
        """One source frame's measurements: intra-session update of the source map; and its
        sightings (`ndfa.change.sightings`)."""
        associations, events = [], []
        for m in frame:
            association, association_events = self._associate("source", self.source, m)
            associations.append(association)
            events += association_events
        self._sighted("source", self.source, associations, sightings)
        return events

    def add_target(self, frame: list[Measurement], sightings: list[Sighting] | None = None) -> list[Event]:
        """One target frame's measurements: update the target map with all of them first (mugs seen
        together are each other's neighbours) and count its sightings, then register if it is time
        to, then test the objects the frame touched."""
        associations, events = [], []
        for m in frame:
            association, association_events = self._associate("target", self.target, m)
            associations.append(association)
            events += association_events
        self._sighted("target", self.target, associations, sightings)
        if not frame:
            return events
        frame_index = frame[0].frame_index
        self._last_frame = frame_index
        was_registered = self.registration is not None
        events += self.registrar.after_target_frame(frame_index, associations)
        if self.registration is None:
            return events
        to_test = {a.object_id for a in associations}
        if not was_registered:
            to_test = set(self.target.objects)  # just registered: decide everything seen so far
        elif any(a.created for a in associations):
            to_test |= self.policy.pending      # a new neighbour may make them decidable
        for object_id in sorted(to_test):
            events += self._test(object_id, frame_index)
        return events

    def finish(self) -> list[Event]:
        """Waiting objects are decided with what there is; then removals and moves."""
        events: list[Event] = []
        if self.registration is not None:
            for object_id in sorted(self.policy.pending):
                events += self._test(object_id, self._last_frame, final=True)
        matched = set(self.partners.values())
        candidates = [i for i in sorted(self.observers) if i not in matched
                      and self.policy.testable(self.source.objects[i].n_measurements, self._sightings_of("source", i))
                      and not self._part_of_matched(i, matched)]
        unshown: dict[int, str] = {}
        if self.registration is not None and candidates:
            to_target = invert_pose(self.registration.transform)
            for source_id in candidates:
                obj = self.source.objects[source_id]
                why = self._unshown("target", apply(to_target, obj.center_world[None])[0], self._own_size("source", obj),
                                   self._reach(obj))
                if why is not None:
                    unshown[source_id] = why
        removed = [i for i in candidates if i not in unshown]
        move_similarity = self.config.evidence.move_similarity
        moved_from = moves(sorted(self.changed), removed, self.target, self.source,
                           self.config.association.shape_similarity if move_similarity is None else move_similarity)
        doubtful = self._doubtful_pairs(moved_from)
        for target_id in sorted(self.in_place_of):
            decision = self.changed[target_id]
            if target_id in doubtful:
                decision = replace(decision, withheld=doubtful[target_id])
                self.unseen[target_id] = decision
                del self.changed[target_id]
            events.append(decision)
        doubtful_removed = {self.in_place_of[t]: why for t, why in doubtful.items() if self.in_place_of[t] in removed}
        removed = [i for i in removed if i not in doubtful_removed]
        unshown |= doubtful_removed
        for target_id, source_id in moved_from.items():
            before = self.changed[target_id]
            events.append(DecisionEvent(
                frame_index=before.frame_index, session="target", object_id=target_id, kind="moved",
                reason=f"changed, and shape-matches removed source object {source_id}",
                center_world=before.center_world, center_source=before.center_source, partner_id=source_id,
                instance_ids=before.instance_ids, partner_instance_ids=self.source.objects[source_id].instance_ids,
                score=before.score, category=self.target.objects[target_id].category, sightings=before.sightings))
        for source_id in removed:
            if source_id in moved_from.values():
                continue
            obj = self.source.objects[source_id]
            events.append(DecisionEvent(
                frame_index=self._last_frame, session="source", object_id=source_id, kind="removed",
                reason="observed but never matched", center_world=obj.center_world, center_source=obj.center_world,
                instance_ids=obj.instance_ids, score=removal_score(len(self.observers[source_id])),
                category=obj.category, sightings=self.sightings["source"].count(source_id)))
        for source_id, why in unshown.items():
            obj = self.source.objects[source_id]
            events.append(DecisionEvent(
                frame_index=self._last_frame, session="source", object_id=source_id, kind="removed",
                reason="observed but never matched", center_world=obj.center_world, center_source=obj.center_world,
                instance_ids=obj.instance_ids, score=removal_score(len(self.observers[source_id])),
                category=obj.category, withheld=why, sightings=self.sightings["source"].count(source_id)))
        return events + self._rotations()

    def _part_of_matched(self, source_id: int, matched: set[int]) -> bool:
        """Whether source object `source_id` stood in the same place as a source object the target
        matched (`_one_object`): one object the source's map held twice, not a removal."""
        return any(self._one_object(self.source, source_id, j) for j in sorted(matched) if j != source_id)

    def _held_twice(self, object_id: int) -> int | None:
        """The target object already decided (found changed, withheld, or unchanged) that target
        object `object_id` stands in the same place as (`_one_object`): the target's map holding one
        object twice, whose second copy is no second change; None when there is none."""
        decided = sorted(set(self.changed) | set(self.unseen) | set(self.partners))
        return next((j for j in decided if j != object_id and self._one_object(self.target, object_id, j)), None)

    def _one_object(self, session_map: SessionMap, first: int, second: int) -> bool:
        """Whether two objects of `session_map` stood in the same place (`ViewsConfig.same_place_m`,
        on one level), so that they are one object the map holds twice: two objects cannot stand
        that close, so either their centers are that close (a bowl's front wall and its back wall,
        whose codes parted: docs/categories.md, "One object twice in a map"), or one of the
        measurements of one was that close to one of the other's (a box whose partial views'
        centers wander by their face, split in two by the map: docs/detector.md, "One object
        twice, by its views"). False when the rule is off (`same_place_m` 0)."""
        if self.config.views.same_place_m <= 0:
            return False
        a, b = session_map.objects[first], session_map.objects[second]
        if session_map._same_place((b.center_world - a.center_world)[None]).any():
            return True
        mine = np.array(a.centers if a.centers else [a.center_world])
        theirs = np.array(b.centers if b.centers else [b.center_world])
        return bool(session_map._same_place((theirs[:, None, :] - mine[None, :, :]).reshape(-1, 3)).any())

    # -- steps ----------------------------------------------------------------------------------

    def _associate(self, session: Session, session_map: SessionMap, m: Measurement) -> tuple[Association, list[Event]]:
        nodes_before = session_map.tree.node_counts()
        a = session_map.update(m)
        obj = session_map.objects[a.object_id]
        events: list[Event] = [AssociationEvent(
            session=session, frame_index=m.frame_index, instance_id=m.instance_id, object_id=a.object_id,
            created=a.created, replaced=a.replaced, distance_m=a.distance_m, similarity=a.similarity,
            candidates=a.candidates, center_world=obj.center_world, shape_code=obj.shape_code, category=obj.category)]
        if a.created or nodes_before != session_map.tree.node_counts():
            events.append(tree_event(session, m.frame_index, session_map))
        return a, events

    def _sighted(self, session: Session, session_map: SessionMap, associations: list[Association],
                 sightings: list[Sighting] | None) -> None:
        """A frame's sightings counted, after its measurements joined `session_map`: the kept ones
        that fall on an object the frame measured, then the frame's own."""
        self.sightings[session].claim(sorted({a.object_id for a in associations}), session_map)
        if sightings:
            self.sightings[session].add(sightings, session_map)

    def _sightings_of(self, session: Session, object_id: int) -> int:
        """The sightings that count toward an object's waiting minimum (`ndfa.change.sightings`):
        none while another object of its map stands in its place (`ViewsConfig.same_place_m`, on
        one level): two objects cannot stand that close, so it is a fragment of that one (a view of
        its upper part, the rest hidden), and its sightings repeat that view."""
        count = self.sightings[session].count(object_id)
        session_map = self._map(session)
        if count == 0 or self.config.views.same_place_m <= 0:
            return count
        obj = session_map.objects[object_id]
        others = [o.center_world for i, o in session_map.objects.items() if i != object_id]
        if others and session_map._same_place(np.array(others) - obj.center_world).any():
            return 0
        return count

    def _looked_at(self, center_source: np.ndarray, source_ids: list[int]) -> list[int]:
        """The source objects a test at `center_source` counts as observed by the target: its
        neighbours and those within `EvidenceConfig.observed_reach_m` of it, within `observed_height_m`."""
        evidence = self.config.evidence
        if evidence.observed_reach_m > 0:
            near = [s for s in self.source.neighbourhood(center_source, evidence.observed_reach_m)
                    if np.linalg.norm(horizontal(self.source.objects[s].center_world - center_source)) <= evidence.observed_reach_m]
            source_ids = sorted(set(source_ids) | set(near))
        if evidence.observed_height_m <= 0:
            return source_ids
        return [s for s in source_ids if abs(self.source.objects[s].center_world[2] - center_source[2]) <= evidence.observed_height_m]

    def _test(self, object_id: int, frame_index: int, final: bool = False) -> list[Event]:
        """The change test of target object O at T_rel t_O, unless O is already marked changed."""
        if object_id in self.changed or object_id in self.unseen:
            return []
        obj = self.target.objects[object_id]
        if not self.policy.testable(obj.n_measurements, self._sightings_of("target", object_id)):
            self.policy.hold(object_id, final)
            return []
        assert self.registration is not None  # objects are tested only once T_rel exists
        transform = self.registration.transform
        rotation = transform[:3, :3]
        center_source = apply(transform, obj.center_world[None])[0]
        margin = self.config.drift.cell_margin_m
        region = self.source.tree.region(center_source, margin)
        source_ids = sorted(region.objects())
        looked_at = self._looked_at(center_source, source_ids)
        for source_id in looked_at:
            self.observers.setdefault(source_id, set()).add(object_id)
        similarity = {s: float(cosine_similarity(obj.shape_code, self.source.objects[s].shape_code)) for s in source_ids}
        shape_similarity = self.config.association.shape_similarity
        verdict = shape_verdict(source_ids, similarity, shape_similarity)
        if verdict is None:  # something around it looks like O: the local graphs decide
            # O's target neighbours: those in the same source cells (why: `docs/detector.md`), where
            # T_rel may have put them (a source neighbour by an edge's target counterpart is one too)
            target_ids = self.registrar.target_objects_in(region, margin)
            target_graph = local_graph(object_id, target_ids, self.target.objects)
            verdict = graph_verdict(target_graph, center_source, source_ids, similarity, self.source.objects, rotation,
                                    shape_similarity, self.config, obj.center_scatter_m)
        swapped_with = None
        if verdict.kind == "unchanged":
            swap = self._swapped(object_id, verdict, source_ids, similarity)
            if swap is not None:
                swapped_with, verdict = swap
        standing = self._in_place(obj, center_source, source_ids) if verdict.kind != "unchanged" else None
        verdict = self.policy.settle(object_id, obj.n_measurements, verdict, final, standing)
        events: list[Event] = [
            graph_event(frame_index, c, center_source, self.source.objects[c.result.source_id].center_world, rotation)
            for c in verdict.comparisons]
        if verdict.kind == "unchanged":
            assert verdict.partner_id is not None  # an "unchanged" verdict names its partner
            self.partners[object_id] = verdict.partner_id
            return events + [self._decision(frame_index, object_id, "unchanged", verdict, center_source)]
        if verdict.kind == "changed":
            self.partners.pop(object_id, None)
            twin = self._held_twice(object_id)
            withheld = (f"one object held twice: target object {twin}, already decided, stood in its place"
                        if twin is not None else self._unshown("source", center_source, self._own_size("target", obj),
                                                                  self._reach(obj)))
            decision = self._decision(frame_index, object_id, "added", verdict, center_source, withheld=withheld)
            (self.changed if decision.withheld is None else self.unseen)[object_id] = decision
            if swapped_with is not None and swapped_with in self.partners:
                events += self._test(swapped_with, frame_index, final)  # the other end of the swap, found unchanged before
            if self.config.waiting.in_place and decision.withheld is None and standing is not None:
                # decided at the end on every view: whether it stands where another stood, see `finish`
                self.in_place_of[object_id] = standing
                return events
            return events + [decision]
        return events  # undecided: O waits (the policy holds it pending)

    def _swapped(self, object_id: int, verdict: Verdict, source_ids: list[int],
                 similarity: dict[int, float]) -> tuple[int, Verdict] | None:
        """(the target object O swapped places with, O's "changed" verdict) when O, found consistent
        with the source object P in its place, is `EvidenceConfig.swap_margin` nearer in code to
        another source object B around it, and a target object standing in B's place is as much
        nearer P than B, each pair that stands in one place seen from a common side
        (`_like_with_like`: one object's codes from opposite sides can cross two objects'); None
        otherwise. O then does not stand where it stood: B is itself."""
        margin = self.config.evidence.swap_margin
        partner_id = verdict.partner_id
        if margin is None or partner_id is None or self.registration is None or self._split(self.target, object_id):
            return None
        if not self._like_with_like(object_id, partner_id):
            return None  # O unlike what stands in its place only as seen from another side
        transform = self.registration.transform
        partner_code = self.source.objects[partner_id].shape_code
        for other_id in sorted(source_ids, key=lambda s: -similarity[s]):
            if similarity[other_id] < similarity[partner_id] + margin:
                return None
            if self._split(self.source, other_id) or self._split(self.source, partner_id):
                continue
            other = self.source.objects[other_id]
            for target_id, target in sorted(self.target.objects.items()):
                if target_id == object_id or self._split(self.target, target_id):
                    continue
                center_source = apply(transform, target.center_world[None])[0]
                if self._in_place(target, center_source, [other_id]) is None:
                    continue
                to_partner = float(cosine_similarity(target.shape_code, partner_code))
                to_other = float(cosine_similarity(target.shape_code, other.shape_code))
                if to_partner >= to_other + margin and self._like_with_like(target_id, other_id):
                    reason = (f"swapped places with target object {target_id}: nearer source object {other_id} "
                              f"(cosine {similarity[other_id]:.2f}) than source object {partner_id} in its place "
                              f"({similarity[partner_id]:.2f}), and target object {target_id} in {other_id}'s place "
                              f"nearer {partner_id} ({to_partner:.2f}) than {other_id} ({to_other:.2f})")
                    return target_id, Verdict("changed", reason, comparisons=verdict.comparisons,
                                              shortfall=verdict.shortfall)
        return None

    def _like_with_like(self, target_id: int, source_id: int) -> bool:
        """Whether a target and a source object were seen from a common side (`EvidenceConfig.side_deg`:
        at least `WaitingConfig.min_measurements` views of each within it of the other's), so that
        their codes' disagreement is the objects', not the sides' (`ndfa.change.sides`); True where
        the test is off or the cameras are not known (a replay)."""
        side_deg = self.config.evidence.side_deg
        target, source = self.target.objects[target_id], self.source.objects[source_id]
        sides = self._sides(target, source) if side_deg is not None else None
        if side_deg is None or sides is None:
            return True
        target_common, source_common = common_side(sides[0], sides[1], side_deg)
        least = self.config.waiting.min_measurements
        return bool(target_common.sum() >= least and source_common.sum() >= least)

    def _split(self, session_map: SessionMap, object_id: int) -> bool:
        """Whether the map holds the object twice (`_one_object` with another of its objects): each
        copy's code is of a part of it, too unsure to say it swapped with another."""
        return any(other != object_id and self._one_object(session_map, object_id, other) for other in session_map.objects)

    def _doubtful_pairs(self, moved_from: dict[int, int]) -> dict[int, str]:
        """The "added" target objects standing in the place of a source object that no other target
        object was found to be (a removal), neither the end of a move, the categories not differing, whose
        codes were compared across no common side (`EvidenceConfig.side_deg`: fewer than
        `WaitingConfig.min_measurements` views of either within it of the other's): one object seen
        from opposite sides can give codes as unlike as two objects', so "replaced" is doubtful
        unless the codes are nearer unrelated objects' (at most `EvidenceConfig.doubtful_share` of
        delta_s). Target object -> why (the pair is withheld; `ndfa.change.sides`)."""
        side_deg = self.config.evidence.side_deg
        if side_deg is None:
            return {}
        doubtful: dict[int, str] = {}
        for target_id, source_id in sorted(self.in_place_of.items()):
            if target_id in moved_from or source_id in moved_from.values():
                continue
            if any(s == source_id and t != target_id for t, s in self.partners.items()):
                continue  # another target object is the source object, unchanged: this one is new beside it
            target, source = self.target.objects[target_id], self.source.objects[source_id]
            if UNKNOWN_CATEGORY not in (target.category, source.category) and target.category != source.category:
                continue  # a cup where a bowl stood: the category says so from any side
            sides = self._sides(target, source)
            if sides is None:
                continue
            target_common, source_common = common_side(sides[0], sides[1], side_deg)
            least = self.config.waiting.min_measurements
            if target_common.sum() >= least and source_common.sum() >= least:
                continue  # compared like with like: the codes' disagreement stands
            similarity = float(cosine_similarity(target.shape_code, source.shape_code))
            if similarity <= self.config.evidence.doubtful_share * self.config.association.shape_similarity:
                continue  # nearer unrelated objects' codes than one object's: a replacement, from any side
            doubtful[target_id] = (
                f"doubtful: target object {target_id} stands where source object {source_id} stood, their "
                f"codes unlike (cosine {similarity:.2f}), but the target saw it from {mean_azimuth_deg(sides[0]):+.0f} deg "
                f"and the source from {mean_azimuth_deg(sides[1]):+.0f} deg, with {int(target_common.sum())} / "
                f"{int(source_common.sum())} views from a common side (fewer than {least}): one object's codes from "
                f"opposite sides can be as unlike as two objects'")
        return doubtful

    def _in_place(self, obj: SessionObject, center_source: np.ndarray, source_ids: list[int]) -> int | None:
        """The nearest source object of `source_ids` standing in O's place: within
        `EvidenceConfig.in_place_m` of T_rel t_O, widened by the two objects' scatter as the in-place
        test is (`DriftConfig.scatter_factor`); None when none does or the test is off."""
        in_place = self.config.evidence.in_place_m
        if in_place <= 0:
            return None
        best, best_d = None, np.inf
        for source_id in source_ids:
            partner = self.source.objects[source_id]
            slack = self.config.drift.scatter_factor * float(np.hypot(obj.center_scatter_m, partner.center_scatter_m))
            d = float(np.linalg.norm(center_source - partner.center_world))
            if d <= in_place + slack and d < best_d:
                best, best_d = source_id, d
        return best

    def _rotations(self) -> list[Event]:
        """At the end, when every view is in: the unchanged target objects whose handle turned
        against their partner's by more than `RotationConfig.threshold_deg` (`ndfa.change.rotation`)."""
        if self.registration is None or self.config.rotation.threshold_deg is None:
            return []
        rotation = self.registration.transform[:3, :3]
        events: list[Event] = []
        for object_id, partner_id in sorted(self.partners.items()):  # the unchanged ones
            obj, partner = self.target.objects[object_id], self.source.objects[partner_id]
            turned = rotation_of(obj, partner, rotation, self.config.rotation, self._sides(obj, partner),
                                 self.config.evidence.side_deg)
            if turned is None:
                continue
            events.append(DecisionEvent(
                frame_index=self._last_frame, session="target", object_id=object_id, kind="rotated",
                reason=(f"turned {turned.angle_deg:+.0f} deg about up against source object {partner_id} "
                        f"(headings from {turned.target.views} and {turned.source.views} views)"),
                center_world=obj.center_world, center_source=apply(self.registration.transform, obj.center_world[None])[0],
                partner_id=partner_id, instance_ids=obj.instance_ids, score=turned.score, angle_deg=turned.angle_deg,
                category=obj.category, withheld=turned.withheld))
        return events

    def _sides(self, target: SessionObject, source: SessionObject) -> tuple[np.ndarray, np.ndarray] | None:
        """The azimuths (source world, `ndfa.change.sides`) of the views of a target and a source
        object (one per entry of their `frames`); None when a camera is not known (a replay) or
        there is no T_rel."""
        if self.registration is None:
            return None
        cameras = self.views["target"].cameras(target.frames), self.views["source"].cameras(source.frames)
        if cameras[0] is None or cameras[1] is None:
            return None
        return (view_azimuths(cameras[0], target.center_world, self.registration.transform[:3, :3]),
                view_azimuths(cameras[1], source.center_world))

    def _decision(self, frame_index: int, object_id: int, kind: DecisionKind, verdict: Verdict,
                  center_source: np.ndarray, withheld: str | None = None) -> DecisionEvent:
        obj = self.target.objects[object_id]
        return DecisionEvent(frame_index=frame_index, session="target", object_id=object_id, kind=kind,
                             reason=verdict.reason, center_world=obj.center_world, center_source=center_source,
                             partner_id=verdict.partner_id, instance_ids=obj.instance_ids,
                             score=decision_score(verdict), category=obj.category, withheld=withheld,
                             sightings=self.sightings["target"].count(object_id))


def reported_changes(decisions: list[DecisionEvent]) -> list[DecisionEvent]:
    """The changes to report from every decision of a run, in order: not "unchanged", not withheld,
    and a target object later found "moved" is reported once, as moved, not also as the "added" it
    was first."""
    changes = [d for d in decisions if d.kind != "unchanged" and d.withheld is None]
    moved = {(d.session, d.object_id) for d in changes if d.kind == "moved"}
    return [d for d in changes if d.kind == "moved" or (d.session, d.object_id) not in moved]


def moves(changed_ids: list[int], removed: list[int], target: SessionMap, source: SessionMap,
          shape_similarity: float) -> dict[int, int]:
    """Changed target object -> the removed source object it moved from, pairs above
    `shape_similarity` (`EvidenceConfig.move_similarity`) taken most similar first, each object
    once: a changed object with a poorer match must not take a removed object from its better one."""
    options = sorted(((float(cosine_similarity(target.objects[t].shape_code, source.objects[s].shape_code)), t, s)
                      for t in changed_ids for s in removed), key=lambda o: (-o[0], o[1], o[2]))
    moved_from: dict[int, int] = {}
    for similarity, target_id, source_id in options:
        if similarity <= shape_similarity:
            break
        if target_id not in moved_from and source_id not in moved_from.values():
            moved_from[target_id] = source_id
    return dict(sorted(moved_from.items()))
