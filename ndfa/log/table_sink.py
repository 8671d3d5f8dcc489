"""Events -> Polars tables, written as parquet into one directory, for analysis in notebooks.

    observations.parquet   one row per instance per frame: pixels, points, skip reason, code, center,
                           handle heading about up and its strength (docs/rotation.md), the NDF's
                           likeliest category and its probability ("unknown", NaN: a model without
                           categories; docs/categories.md); a skipped one's sighting (`sighting_x/y/z`:
                           its points' centroid, ndfa.change.sightings)
    associations.parquet   the intra-session update of each measurement
    objects.parquet        each session's objects at the end (last state of every object, its category)
    tree_nodes.parquet     each session's interval-tree nodes at the end
    registration.parquet   every registration attempt, with T_rel when found
    graphs.parquet         every local-graph comparison, one row per compared edge pair (or one
                           row without an edge for a fallback comparison)
    decisions.parquet      every change test and the final removals/moves, with its score (>= 0.5:
                           a change; docs/scores.md) and the ground-truth change of the object's
                           mask when the recordings carry it, and whether a change's kind is right
                           for it (`kind_right`; a move from another mask is not); `reported`: the
                           changes the run reports (an "added" later found "moved" is reported as
                           the move); a rotation's turn in `angle_deg`; the object's `category`;
                           `withheld`: why a change is not reported (its place not shown by the
                           other session: ndfa.change.sight); `sightings`: the object's sightings
    timings.parquet        ms per stage per frame
    pose_quality.parquet   one row per session whose poses were estimated: the verdict (good /
                           doubtful / unusable), the estimated error and the figures behind it
                           (`ndfa.trajectory.quality`, docs/pose_quality.md)
    history.parquet        a run over more than two sessions (`ndfa.run.sessions`): one row per object
                           per session (`ndfa.core.sessions.HistoryRow`, with its category); its registration, graphs
                           and decisions rows then name their `pair` ("0-1", ...), its sessions are
                           named `session_0`, ..., and positions are in the first session's world

Vectors are list columns (center_x/y/z as plain columns for easy filtering). The tables are
rewritten every `flush_every` frames and at the end (each atomically), so an interrupted run
leaves tables that are complete up to a recent frame (`ndfa detect` then puts back what the folder
held before: `ndfa.io.atomic.all_or_nothing`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

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
from ndfa.core.sessions import HistoryEvent, HistoryRow, PairEvent
from ndfa.io.atomic import write_parquet
from ndfa.io.recording.ground_truth import kind_is_right

TABLES = ("observations", "associations", "objects", "tree_nodes", "registration", "graphs", "decisions", "timings",
          "pose_quality")


class TableSink:
    def __init__(self, directory: Path, truth: dict[int, str] | None = None, flush_every: int = 100,
                 identical_moves: frozenset[tuple[int, int]] = frozenset()) -> None:
        """truth: mask instance id -> ground-truth change ("unchanged", "added", ...), when known;
        identical_moves: its (removed, added) mugs of one model (`ground_truth.identical_moves`)."""
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.truth = truth
        self.identical_moves = identical_moves
        self.flush_every = flush_every
        self.rows: dict[str, list[dict]] = {name: [] for name in TABLES if name not in ("objects", "tree_nodes")}
        self._objects: dict[tuple[str, int], dict] = {}
        self._trees: dict[str, TreeEvent] = {}
        self._frames = 0
        self._pair: str | None = None  # the pair of sessions the detector's events compare (many sessions)
        self._history: list[dict] | None = None

    def log(self, event: Event | PairEvent | HistoryEvent) -> None:
        if isinstance(event, PairEvent):
            self._pair = event.label
            if event.truth is not None:
                self.truth = event.truth  # the changes between this pair's sessions
                self.identical_moves = event.identical_moves
            return
        if isinstance(event, HistoryEvent):
            self._history = [_history_row(row) for row in event.rows]
            return
        if self._pair is None or not isinstance(event, (RegistrationEvent, GraphEvent, DecisionEvent)):
            self._log(event)
            return
        names = ("registration", "graphs", "decisions")
        before = [len(self.rows[name]) for name in names]
        self._log(event)
        for name, start in zip(names, before):
            for row in self.rows[name][start:]:
                row["pair"] = self._pair

    def _log(self, event: Event) -> None:
        if isinstance(event, FrameEvent):
            self._frames += 1
            if self._frames % self.flush_every == 0:
                self.flush()
        elif isinstance(event, ObservationEvent):
            self.rows["observations"].append({
                "session": event.session, "frame": event.frame_index, "instance_id": event.instance_id,
                "n_pixels": event.n_pixels, "n_points": event.n_points, "skipped": event.skipped,
                "touches_border": event.touches_border, "mean_occupancy": event.mean_occupancy,
                **_xyz("center", event.center_world), "shape_code": _list(event.shape_code),
                "heading_deg": float(np.degrees(event.heading_rad)), "heading_strength": event.heading_strength,
                "category": event.category, "category_probability": event.category_probability,
                **_xyz("sighting", event.sighting_world), "truth": self._truth(event.instance_id)})
        elif isinstance(event, AssociationEvent):
            row = {"session": event.session, "frame": event.frame_index, "instance_id": event.instance_id,
                   "object_id": event.object_id, "created": event.created, "replaced": event.replaced,
                   "distance_m": event.distance_m, "similarity": event.similarity, "candidates": event.candidates}
            self.rows["associations"].append(row)
            key = (event.session, event.object_id)
            previous = self._objects.get(key, {"first_frame": event.frame_index, "measurements": 0, "instance_ids": []})
            self._objects[key] = {
                "session": event.session, "object_id": event.object_id, "first_frame": previous["first_frame"],
                "last_frame": event.frame_index, "measurements": previous["measurements"] + 1,
                "instance_ids": sorted(set(previous["instance_ids"]) | {event.instance_id}),
                **_xyz("center", event.center_world), "shape_code": _list(event.shape_code), "category": event.category,
                "truth": self._truth(event.instance_id if not previous["instance_ids"] else previous["instance_ids"][0])}
        elif isinstance(event, TreeEvent):
            self._trees[event.session] = event
        elif isinstance(event, RegistrationEvent):
            self.rows["registration"].append({
                "frame": event.frame_index, "method": event.method, "accepted": event.accepted, "pairs": event.n_pairs,
                "hypotheses": event.n_hypotheses, "inliers": len(event.inlier_pairs), "residual_m": event.residual_m,
                "inlier_pairs": [list(p) for p in event.inlier_pairs], "evidence": event.evidence,
                "transform": _list(event.transform.ravel()) if event.transform is not None else None})
        elif isinstance(event, GraphEvent):
            base = {"frame": event.frame_index, "target_id": event.target_id, "source_id": event.source_id,
                    "similarity": event.similarity, "mode": event.mode, "consistent": event.consistent,
                    "distance_m": event.distance_m}
            if not event.edges:
                self.rows["graphs"].append(base | {"target_neighbour": None, "source_neighbour": None,
                                                    "edge_error_m": None, "edge_consistent": None})
            for target_neighbour, source_neighbour, error, ok in event.edges:
                self.rows["graphs"].append(base | {"target_neighbour": target_neighbour, "source_neighbour": source_neighbour,
                                                    "edge_error_m": error, "edge_consistent": ok})
        elif isinstance(event, DecisionEvent):
            position = event.center_source if event.center_source is not None else event.center_world
            self.rows["decisions"].append({
                "frame": event.frame_index, "session": event.session, "object_id": event.object_id, "kind": event.kind,
                "reason": event.reason, **_xyz("position", position), "partner_id": event.partner_id,
                "instance_ids": list(event.instance_ids), "partner_instance_ids": list(event.partner_instance_ids),
                "score": event.score, "angle_deg": event.angle_deg, "category": event.category,
                "withheld": event.withheld, "sightings": event.sightings,
                "truth": self._truth(event.instance_ids[0]) if event.instance_ids else None,
                "kind_right": self._kind_right(event)})
        elif isinstance(event, PoseQualityEvent):
            self.rows["pose_quality"].append({"session": event.session, "verdict": event.verdict,
                                              "estimated_error_cm": event.error_cm} | event.figures)
        elif isinstance(event, TimingEvent):
            self.rows["timings"].append({"session": event.session, "frame": event.frame_index} | event.stage_ms)

    def tables(self) -> dict[str, pl.DataFrame]:
        tables = {name: pl.DataFrame(rows, infer_schema_length=None) for name, rows in self.rows.items()}
        if self.rows["decisions"]:
            tables["decisions"] = tables["decisions"].with_columns(
                reported=pl.Series(_reported(self.rows["decisions"]), dtype=pl.Boolean))
        tables["objects"] = pl.DataFrame(list(self._objects.values()), infer_schema_length=None)
        nodes = []
        for session, tree in self._trees.items():
            for axis, intervals in (("x", tree.x_intervals), ("y", tree.y_intervals)):
                for index, (low, high) in enumerate(intervals):
                    objects = sorted({o for i, j, ids in tree.cells if (i if axis == "x" else j) == index for o in ids})
                    nodes.append({"session": session, "axis": axis, "node": index, "low": float(low),
                                  "high": float(high), "objects": objects})
            for index, ((low, high), objects) in enumerate(zip(tree.z_intervals, tree.z_objects)):  # T_z's nodes
                nodes.append({"session": session, "axis": "z", "node": index, "low": float(low), "high": float(high),
                              "objects": list(objects)})
        tables["tree_nodes"] = pl.DataFrame(nodes, infer_schema_length=None)
        if self._history is not None:
            tables["history"] = pl.DataFrame(self._history, schema=HISTORY_SCHEMA)
        return tables

    def flush(self) -> None:
        for name, table in self.tables().items():
            write_parquet(table, self.directory / f"{name}.parquet")

    def close(self) -> None:
        self.flush()

    def _kind_right(self, event: DecisionEvent) -> bool | None:
        """Whether a reported change's kind is right for its mask's true change (`kind_is_right`);
        None for "unchanged" decisions and where the truth or the mask is unknown."""
        if self.truth is None or event.kind == "unchanged" or not event.instance_ids:
            return None
        partner = event.partner_instance_ids[0] if event.partner_instance_ids else None
        return kind_is_right(event.kind, event.instance_ids[0], partner, self.truth, self.identical_moves)

    def _truth(self, instance_id: int) -> str | None:
        if self.truth is None:
            return None
        return self.truth.get(int(instance_id), "unchanged")


def _reported(decisions: list[dict]) -> list[bool]:
    """Which decision rows are reported changes (`ndfa.change.detector.reported_changes`): not
    "unchanged", not withheld, and a target object's "added" only when it was not later found "moved"."""
    def key(row: dict) -> tuple:
        return row.get("pair"), row["session"], row["object_id"]

    moved = {key(row) for row in decisions if row["kind"] == "moved"}
    return [row["kind"] != "unchanged" and row.get("withheld") is None and (row["kind"] == "moved" or key(row) not in moved)
            for row in decisions]


HISTORY_SCHEMA = {
    "object": pl.Int64, "session": pl.Int64, "session_name": pl.String, "present": pl.Boolean,
    "center_x": pl.Float64, "center_y": pl.Float64, "center_z": pl.Float64, "session_object": pl.Int64,
    "instance_id": pl.Int64, "decision": pl.String, "score": pl.Float64, "partner": pl.Int64, "reason": pl.String,
    "category": pl.String,
}


def _history_row(row: HistoryRow) -> dict:
    """One history row as the table holds it: the center as plain columns, in the first session's world."""
    return {"object": row.object, "session": row.session, "session_name": row.session_name, "present": row.present,
            **_xyz("center", row.center_first), "session_object": row.session_object,
            "instance_id": row.instance_id, "decision": row.decision, "score": row.score, "partner": row.partner,
            "reason": row.reason, "category": row.category}


def _xyz(prefix: str, vector: np.ndarray | None) -> dict:
    if vector is None:
        return {f"{prefix}_x": None, f"{prefix}_y": None, f"{prefix}_z": None}
    return {f"{prefix}_{axis}": float(v) for axis, v in zip("xyz", vector)}


def _list(vector: np.ndarray | None) -> list[float] | None:
    return None if vector is None else [float(v) for v in np.ravel(vector)]
