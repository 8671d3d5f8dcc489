"""The whole method for one frame at a time: observations -> NDF codes -> change detector -> events.

    pipeline = ChangeDetectionPipeline(PipelineConfig())
    detector = pipeline.new_detector()
    for frame in source frames:  events = pipeline.process("source", frame, detector)
    for frame in target frames:  events = pipeline.process("target", frame, detector)
    events = detector.finish()

The pipeline holds no detector: a run over many sessions feeds each session's measurements to the
detectors of the pairs it belongs to (`ndfa.run.sessions`). Reading recordings and logging events
happen outside (`ndfa.run`, `ndfa.log`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

from ndfa.change.associate import Measurement
from ndfa.change.detector import ChangeDetector, DetectorConfig
from ndfa.change.sight import SightRule
from ndfa.change.sightings import Sighting
from ndfa.core.events import SESSIONS, Event, FrameEvent, ObservationEvent, Session, TimingEvent
from ndfa.core.frame import Frame
from ndfa.core.geometry import transform_points
from ndfa.ndf.encoder import EncoderConfig, NDFEncoder, ObjectCode
from ndfa.ndf.reuse import CodeReuse, ReuseConfig
from ndfa.perception.observations import Observation, ObservationConfig, SkippedObservation, extract_observations
from ndfa.perception.segmentation import PlaneTracker, segment_frame
from ndfa.perception.segmentation_config import GATES, SegmentationConfig

# The mean occupancy a segment's observation must reach, per gate (`PipelineConfig.min_segment_occupancy`):
# the mugs' NDF's test of mug-likeness, and none for objects of every category.
SEGMENT_OCCUPANCY = {"mugs": 0.63, "objects": 0.0}


@dataclass(frozen=True)
class PipelineConfig:
    """The stages' configs.

    segmentation: a frame without instance masks is segmented geometrically with this (support
    planes removed, DBSCAN; `ndfa.perception.segmentation`) and the sinks see the segmented
    frame; None: such a frame gives no observations.
    min_segment_occupancy: an observation of a segmented frame (not of a mask) is used only if the
        NDF's mean occupancy over its reconstruction reaches this; None (the default): the gate's
        own bar (`SEGMENT_OCCUPANCY`). With the mugs' gate it is a test of mug-likeness: the NDF
        knows mugs, and clutter of mug size that passed the segmentation's gate fits it worse (v1
        weights, redkitchen: real mug views 0.61-0.83, the rest median 0.63, a third below 0.6;
        docs/segmentation.md). NDF v2's smaller decoder is less sure of everything (kitchen mug
        views 0.61-0.68+, median 0.68): at 0.6 a 3-view counter segment became an object and was
        reported "added" on the kitchen halves with given poses; 0.63 keeps it out, and each mug
        still one object (2026-12-02). With the objects' gate there is no bar: a test of
        mug-likeness turns away the other categories, and NDF v3's occupancy does not tell an
        object from what is none (docs/categories.md, "The occupancy bar was the mugs'"). 0: off.
    reuse: whether an observation of a masked frame may take the code of a view of the same object
        encoded a frame or two before, when its view has barely changed (`ndfa.ndf.reuse`; off by
        default: the paper encodes every observation). Segmented frames are always encoded: a
        segment's points change with the clustering from frame to frame, and on `paper --raw
        --textures` reuse moved decisions (docs/speed.md).
    gate: which segments are objects (`GATES`; docs/segmentation.md, "Objects, not mugs")."""

    observation: ObservationConfig = field(default_factory=ObservationConfig)
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    weights: Path | None = None      # NDF checkpoint; None: the shipped one
    segmentation: SegmentationConfig | None = field(default_factory=SegmentationConfig)
    min_segment_occupancy: float | None = None
    reuse: ReuseConfig = field(default_factory=ReuseConfig)
    gate: str = "auto"

    def __post_init__(self) -> None:
        if self.gate not in GATES:
            raise ValueError(f"unknown objectness gate {self.gate!r}; expected one of {', '.join(GATES)}")


@dataclass(frozen=True)
class ObservedFrame:
    """A frame through the stages that do not depend on the detector: its observations (from its
    masks, or from its segmentation) and, once encoded, their NDF codes."""

    frame: Frame                       # with the segmentation's instances when it was segmented
    segmented: bool
    observations: list[Observation]
    skipped: list[SkippedObservation]
    stage_ms: dict[str, float]         # reading (when staged), segmentation (when segmented), perception, encoding
    codes: list[ObjectCode] | None = None


class ChangeDetectionPipeline:
    """perceive -> encode -> decide, one frame at a time. The first two are per frame and hold no
    state but what a caller hands them for a session (its plane tracker, its recent codes; a
    caller may run them ahead, in other threads: `ndfa.run.detect`); `decide` feeds the
    detector, in frame order. `process` is the three in a row."""

    def __init__(self, config: PipelineConfig = PipelineConfig(), encoder: NDFEncoder | None = None) -> None:
        self.config = config
        self.encoder = encoder or NDFEncoder(config.weights, config.encoder)
        objects = config.gate == "objects" or (config.gate == "auto" and bool(self.encoder.categories))
        self.gate = "objects" if objects else "mugs"  # what `config.gate` came to
        # The segmentation this pipeline runs on frames without masks (None: none).
        self.segmentation = config.segmentation.for_objects() if objects and config.segmentation else config.segmentation
        # The bar a segment's mean occupancy must reach (`PipelineConfig.min_segment_occupancy`).
        self.min_segment_occupancy = SEGMENT_OCCUPANCY[self.gate] if config.min_segment_occupancy is None \
            else config.min_segment_occupancy

    def new_detector(self) -> ChangeDetector:
        """A change detector with this pipeline's parameters: one per pair of sessions."""
        observation = self.config.observation
        return ChangeDetector(self.config.detector, SightRule(observation.min_pixels, observation.min_depth_m,
                                                              observation.max_depth_m, observation.skip_border))

    def new_code_reuse(self) -> CodeReuse | None:
        """What a session's pass hands to `encode` so that its observations may reuse codes (None:
        reuse off, `PipelineConfig.reuse`): one per session, its frames in order."""
        return CodeReuse(self.encoder, self.config.reuse) if self.config.reuse.enabled else None

    def new_plane_tracker(self) -> PlaneTracker | None:
        """What a session's pass hands to `perceive` so that a segmented frame's support planes
        are tracked from the previous frame's (`SegmentationConfig.plane_search_every`): one per
        session, its frames in order. None: no segmentation, or a full search in every frame."""
        segmentation = self.segmentation
        if segmentation is None or segmentation.plane_search_every == 1:
            return None
        return PlaneTracker(segmentation.plane_search_every)

    def process(self, session: Session, frame: Frame, detector: ChangeDetector,
                full_reconstruction: bool = True) -> list[Event]:
        """One frame's events. full_reconstruction False (for a caller without sinks): each
        observation's reconstruction is decoded only as far as the decisions need it
        (`NDFEncoder.encode_batch`); the events and decisions are the same, but an event's
        `mean_occupancy` and `reconstruction_world` are then the coarse grid's."""
        return self.decide(session, self.encode(self.perceive(frame), full_reconstruction), detector)

    def perceive(self, frame: Frame, tracker: PlaneTracker | None = None) -> ObservedFrame:
        """The frame's observations: of its masks, else of its segmentation (if on); `tracker`
        (`new_plane_tracker`, the session's frames in order): its planes tracked."""
        started = time.perf_counter()
        stage_ms = {}
        segmentation = self.segmentation
        segmented = frame.instances is None and segmentation is not None
        if segmented:
            assert segmentation is not None
            frame = replace(frame, instances=segment_frame(frame, segmentation, tracker))
            stage_ms["segmentation"] = (time.perf_counter() - started) * 1e3
            started = time.perf_counter()
        # Sightings (small masks' centroids, `ndfa.change.sightings`) only of a recording's masks: a
        # small segment of ndfa's own is as often a piece of clutter or of a larger object.
        observation = replace(self.config.observation, sighting_pixels=0) if segmented else self.config.observation
        observations, skipped = extract_observations(frame, observation)
        stage_ms["perception"] = (time.perf_counter() - started) * 1e3
        return ObservedFrame(frame, segmented, observations, skipped, stage_ms)

    def encode(self, observed: ObservedFrame, full_reconstruction: bool = True, reuse: CodeReuse | None = None) -> ObservedFrame:
        """Its observations' NDF codes (`process` says what `full_reconstruction` does); `reuse`
        (`new_code_reuse`, the session's frames in order): a masked frame's observations may take
        earlier views' codes (`PipelineConfig.reuse`)."""
        started = time.perf_counter()
        # The mean occupancy decides the objectness gate of segments (where it has a bar: not the
        # objects' gate) and, with "best" fusion, which measurement an object keeps; elsewhere only
        # whether the reconstruction is empty decides.
        gated = observed.segmented and self.min_segment_occupancy > 0.0
        full = full_reconstruction or gated or self.config.detector.views.fusion == "best"
        clouds = [o.points_camera for o in observed.observations]
        if reuse is not None and not observed.segmented:
            codes = reuse.encode(clouds, observed.frame.pose_world_camera, full)
        else:
            codes = self.encoder.encode_batch(clouds, [observed.frame.pose_world_camera] * len(clouds), full_reconstruction=full)
        return replace(observed, codes=codes,
                       stage_ms=observed.stage_ms | {"encoding": (time.perf_counter() - started) * 1e3})

    def decide(self, session: Session, observed: ObservedFrame, detector: ChangeDetector,
               also_source_of: ChangeDetector | None = None) -> list[Event]:
        """An encoded frame's measurements into `detector` as a frame of `session` ("source" or
        "target"): the frame's events. `also_source_of`: the detector of the next pair, whose
        source this session is, takes the same measurements (its events are not returned: they
        repeat the association this frame's events show)."""
        if session not in SESSIONS:
            raise ValueError(f"session must be one of {SESSIONS}, got {session!r}")
        started, registering = time.perf_counter(), detector.registrar.seconds
        events, measurements, sightings = self.measure(session, observed)
        frame = observed.frame
        for taker, role in ((detector, session), (also_source_of, "source")):
            if taker is not None:  # what the frame showed: a change's place must have been shown
                taker.add_view(role, frame.index, frame.depth, frame.K, frame.pose_world_camera)  # type: ignore[arg-type]
        events += (detector.add_source if session == "source" else detector.add_target)(measurements, sightings)
        if also_source_of is not None:
            also_source_of.add_source(measurements, sightings)
        registration_ms = (detector.registrar.seconds - registering) * 1e3  # T_rel's estimation, within the step
        events.append(TimingEvent(session=session, frame_index=observed.frame.index, stage_ms=observed.stage_ms | {
            "detection": (time.perf_counter() - started) * 1e3 - registration_ms, "registration": registration_ms}))
        return events

    def measure(self, session: Session, observed: ObservedFrame
                ) -> tuple[list[Event], list[Measurement], list[Sighting]]:
        """An encoded frame's events (the frame, each observation or why it was skipped) and the
        measurements and sightings the detector takes from it (`Measurement.of`, `Sighting.of`)."""
        if observed.codes is None:
            raise ValueError("measure() needs an encoded frame (encode())")
        frame = observed.frame
        events: list[Event] = [FrameEvent(session=session, frame=frame)]
        measurements: list[Measurement] = []
        sightings: list[Sighting] = []
        for skipped_observation in observed.skipped:
            center = skipped_observation.center_camera
            event = ObservationEvent(
                session=session, frame_index=frame.index, instance_id=skipped_observation.instance_id,
                n_pixels=skipped_observation.n_pixels, skipped=skipped_observation.reason,
                sighting_world=None if center is None else transform_points(frame.pose_world_camera, center[None])[0])
            events.append(event)
            sighting = Sighting.of(event)
            if sighting is not None:
                sightings.append(sighting)
        for observation, code in zip(observed.observations, observed.codes):
            # No grid point above v0: the NDF does not see a whole object in this view (on the
            # `paper` scene such views gave centers several cm off); logged, not used.
            empty = code.mean_occupancy <= 0.0
            skip: str | None = "empty reconstruction" if empty else None
            if not empty and observed.segmented and code.mean_occupancy < self.min_segment_occupancy:
                skip = (f"segment not mug-like: mean occupancy {code.mean_occupancy:.2f} "
                        f"< {self.min_segment_occupancy}")
            event = ObservationEvent(
                session=session, frame_index=frame.index, instance_id=observation.instance_id,
                n_pixels=observation.n_pixels, skipped=skip,
                n_points=len(observation.points_camera), touches_border=observation.touches_border,
                points_world=transform_points(frame.pose_world_camera, observation.points_camera),
                shape_code=code.shape_code, center_world=code.center_world, mean_occupancy=code.mean_occupancy,
                reconstruction_world=code.reconstruction, heading_rad=code.heading_rad,
                heading_strength=code.heading_strength, category=code.category,
                category_probability=code.category_probability)
            events.append(event)
            if skip is None:
                measurements.append(Measurement.of(event))
        return events, measurements, sightings
