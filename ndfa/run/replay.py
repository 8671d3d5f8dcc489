"""Re-run the change detector on the measurements of an earlier run's observations table.

Perception and encoding are most of a run's time, and they do not depend on the detector's
parameters; the observations table (`ndfa detect --tables DIR`) holds every measurement the
detector saw. Replaying it with another `DetectorConfig` takes well under a second, which is what
parameter studies and error analysis in a notebook need:

    observations = pl.read_parquet("out/tables/observations.parquet")
    result = replay(observations, DetectorConfig(association=AssociationConfig(shape_similarity=0.8)))
    score_replay(result)    # TP/FP/FN over the instances the table labels (`ndfa.eval.runs`)

The score counts the instances the table has a label for, visible as `ndfa.eval.scoring` asks; it
matches `ndfa detect`'s own score (from the recording's ground truth) whenever every mug of the
ground truth appears in the table, which a mug that is never in view does not.

Every decision carries a score (`DecisionEvent.score`, docs/scores.md); `reported_at` gives the
instances a run reports when its decisions are thresholded at another score than the detector's
own 0.5 -- one replay, then any number of thresholds (`ndfa eval --pr-curve`):

    score_replay(result, 0.3)    # TP/FP/FN with every decision scoring >= 0.3 reported
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import polars as pl

from ndfa.change.associate import Measurement
from ndfa.change.detector import ChangeDetector, DetectorConfig, reported_changes
from ndfa.change.register import RegistrationPrior
from ndfa.change.sightings import Sighting
from ndfa.core.conventions import UNKNOWN_CATEGORY, is_visible
from ndfa.core.events import CHANGE_SCORE, SESSIONS, DecisionEvent, ObservationEvent


@dataclass
class ReplayResult:
    changes: list[DecisionEvent]  # as `ndfa detect` reports them: a moved object replaces its "added"
    events: list                  # every event of the detector, in order
    detector: ChangeDetector      # its final state (maps, registration), for inspection
    decisions: list[DecisionEvent] = field(default_factory=list)  # every decision, "unchanged" too, with scores
    truth: dict | None = None     # the table's labels, as `ndfa.eval.scoring.score` takes them
    visible: dict[str, set[int]] = field(default_factory=dict)    # per session, the instances the table saw


def reported_at(decisions: list[DecisionEvent], threshold: float = CHANGE_SCORE) -> list[int]:
    """The mask ids a run reports when each of its decisions is reported as a change iff its score
    is at least `threshold`: an "unchanged" target object whose test ever scored that high counts
    as found changed (online, a change is reported the first time it is found), a change scoring
    lower is withheld, and so is one the detector withheld (`DecisionEvent.withheld`: its place not
    shown by the other session). At `CHANGE_SCORE` these are exactly the detector's reported changes.

    Approximate away from 0.5, stated in docs/scores.md: the detector is not re-run at the
    threshold, so an object withheld here is not tested again, and removals and moves stay the
    ones the detector found at 0.5 (each kept when its own score passes).
    """
    reported = [d for d in decisions if d.score >= threshold and d.withheld is None]
    return sorted({i for d in reported for i in d.reported_instances})


def measurements_by_frame(observations: pl.DataFrame, session: str) -> list[list[Measurement]]:
    """The measurements of one session, grouped by frame in frame order (skipped views left out)."""
    used = observations.filter((pl.col("session") == session) & pl.col("skipped").is_null()).sort("frame", "instance_id")
    frames: dict[int, list[Measurement]] = {}
    for row in used.iter_rows(named=True):
        frames.setdefault(row["frame"], []).append(Measurement.of(observation_of(row)))
    return [frames[f] for f in sorted(frames)]


def frames_of(observations: pl.DataFrame, session: str) -> list[tuple[list[Measurement], list[Sighting]]]:
    """The measurements and sightings (`ndfa.change.sightings`) of one session, grouped by frame
    in frame order, as the run handed them to its detector (a table written before sightings had
    none)."""
    measurements = measurements_by_frame(observations, session)
    frames: dict[int, tuple[list[Measurement], list[Sighting]]] = {m[0].frame_index: (m, []) for m in measurements}
    if "sighting_x" in observations.columns:
        sighted = observations.filter((pl.col("session") == session) & pl.col("sighting_x").is_not_null())
        for row in sighted.sort("frame", "instance_id").iter_rows(named=True):
            frames.setdefault(row["frame"], ([], []))[1].append(Sighting(
                row["frame"], row["instance_id"], np.array([row["sighting_x"], row["sighting_y"], row["sighting_z"]]),
                row["n_pixels"]))
    return [frames[f] for f in sorted(frames)]


def observation_of(row: dict) -> ObservationEvent:
    """An encoded observation as the observations table holds it (what the detector needs of it)."""
    return ObservationEvent(
        session=row["session"], frame_index=row["frame"], instance_id=row["instance_id"], n_pixels=row["n_pixels"],
        skipped=row["skipped"], shape_code=np.asarray(row["shape_code"]),
        center_world=np.array([row["center_x"], row["center_y"], row["center_z"]]),
        mean_occupancy=row["mean_occupancy"],
        # the handle heading (docs/rotation.md); a table written before it had none
        heading_rad=np.radians(np.nan if row.get("heading_deg") is None else row["heading_deg"]),
        heading_strength=row.get("heading_strength") or 0.0,
        # the NDF's category (docs/categories.md); a table written before it had none
        category=row.get("category") or UNKNOWN_CATEGORY,
        category_probability=np.nan if row.get("category_probability") is None else row["category_probability"])


def replay(observations: pl.DataFrame, config: DetectorConfig = DetectorConfig(),
           prior: RegistrationPrior | None = None) -> ReplayResult:
    """The detector on the table's measurements; `prior`: the run's scene-level T_rel hypothesis
    (`DetectionResult.alignment.prior()`), which the run offered its detector, if any."""
    detector = ChangeDetector(config)
    if prior is not None:
        detector.add_registration_prior(prior)
    events: list = []
    for frame, sightings in frames_of(observations, "source"):
        events += detector.add_source(frame, sightings)
    for frame, sightings in frames_of(observations, "target"):
        events += detector.add_target(frame, sightings)
    events += detector.finish()
    decisions = [e for e in events if isinstance(e, DecisionEvent)]
    changes = reported_changes(decisions)
    seen = observations.filter(is_visible(pl.col("n_pixels")))
    visible = {s: set(seen.filter(pl.col("session") == s)["instance_id"].to_list()) for s in SESSIONS}
    return ReplayResult(changes, events, detector, decisions, _truth(observations), visible)


def _truth(observations: pl.DataFrame) -> dict | None:
    """A ground-truth dict (as `ndfa.eval.scoring.score` takes it) from the table's per-instance labels."""
    if "truth" not in observations.columns or observations["truth"].null_count() == len(observations):
        return None
    labels = observations.select("instance_id", "truth").drop_nulls().unique("instance_id")
    return {"objects": [{"instance_id": i, "change": t} for i, t in labels.iter_rows()]}
