"""Which true item every object of a segmented (raw) run stands on, and what a replay of its
observations reports, scored by position (issue 33: tracing the raw multi-category false reports
and misses to their cause; docs/categories.md).

A raw run's observations have no instance ids (a segment's id is its number in its frame), so the
observations table cannot say which object a measurement saw and `ndfa.run.replay`'s score needs
labels. This study runs `ndfa detect` once and keeps, beside its tables and JSON, what scoring by
position needs (each session's camera poses as the run used them against the true ones, and the
scene alignment it offered the detector); then any replay of the observations with another
`DetectorConfig` is scored as `ndfa detect` scores (`ndfa.eval.position_match`), in a second.

    # one run (slow: odometry, segmentation): OUT/tables, OUT/summary.json, OUT/trace.pkl, OUT/objects.txt
    python studies/raw_trace.py run SRC TGT OUT [ndfa detect options, e.g. --weights objects]
    # the replay of OUT's observations, scored by position; every object matched to the truth
    python studies/raw_trace.py replay OUT [--weights objects]

`objects.txt`: for each object of both maps, the item nearest its center (true world, mapped by
the cameras that saw it), that item's category and change, the object's category and views.
A replay has no depth views, so the place rule takes every place as shown (its withheld changes
are reported).
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np
import polars as pl

from ndfa.change.detector import DetectorConfig
from ndfa.eval import position_score, runs
from ndfa.eval.position_match import align_worlds, match_object, score_by_position
from ndfa.eval.position_score import reported_object, reports_of
from ndfa.run.replay import replay


def _truth_by_id(truth: dict) -> dict[int, tuple[str, str]]:
    items = {int(o["instance_id"]): (o.get("category", "mug"), o.get("change", "unchanged")) for o in truth["objects"]}
    items |= {int(c["instance_id"]): (str(c.get("category")), "clutter") for c in truth.get("clutter", [])}
    return items


def describe_objects(maps: dict, cameras: dict, pose_true_run: dict, truth: dict) -> list[str]:
    """One line per object of both maps: the true item it stands on."""
    names = _truth_by_id(truth)
    lines = []
    for session, session_map in maps.items():
        for object_id, obj in sorted(session_map.objects.items()):
            reported = reported_object(maps, cameras, session, object_id, obj.center_world)
            match = match_object(reported, truth, pose_true_run[session])
            item = match.instance_id
            category, change = names.get(item, ("-", "-")) if item is not None else ("-", "nothing")
            lines.append(f"{session} {object_id:3d} named {obj.category:7s} views {obj.n_measurements:3d} "
                         f"frames {obj.first_frame}-{obj.last_frame} -> item {item} {category} {change} "
                         f"at {match.distance_m * 100:.1f} cm{'' if item is not None else ' nearest ' + str(match.nearest)}")
    return lines


def run(source: str, target: str, out: Path, options: list[str]) -> None:
    from ndfa.cli.app import main

    out.mkdir(parents=True, exist_ok=True)
    original = position_score.score_segmented_run

    def traced(changes, detector, readers, worlds, notes):
        result = original(changes, detector, readers, worlds, notes)
        cameras, pose_true_run = {}, {}
        for session, reader in readers.items():
            pairs = {}
            for frame in reader.frames():
                if worlds[session].poses is not None and frame.index not in worlds[session].poses:
                    continue  # a run on every n-th frame estimates those frames' poses alone
                true = frame.pose_world_camera_true if frame.pose_world_camera_true is not None else frame.pose_world_camera
                pairs[frame.index] = (worlds[session].apply(frame).pose_world_camera, true)
            cameras[session] = pairs
            pose_true_run[session] = align_worlds([r for r, _ in pairs.values()], [t for _, t in pairs.values()])[0]
        truth = dict(readers["target"].ground_truth or {})
        visible: dict = {}
        for reader in readers.values():
            listed = (reader.ground_truth or {}).get("visible")
            visible |= listed if isinstance(listed, dict) else {}
        truth["visible"] = visible or None
        maps = {"source": detector.source, "target": detector.target}
        with open(out / "trace.pkl", "wb") as file:
            pickle.dump({"cameras": cameras, "pose_true_run": pose_true_run, "truth": truth,
                         "priors": list(detector.registrar.priors)}, file)
        (out / "objects.txt").write_text("\n".join(describe_objects(maps, cameras, pose_true_run, truth)) + "\n")
        return result

    runs.score_segmented_run = traced
    sys.argv = ["ndfa", "detect", source, target, "--tables", str(out / "tables"), "--json", str(out / "summary.json"),
                *options]
    main()


def score_replay_by_position(result, trace: dict) -> tuple:
    maps = {"source": result.detector.source, "target": result.detector.target}
    reports = reports_of(result.changes, maps, trace["cameras"])
    return score_by_position(reports, trace["truth"], trace["pose_true_run"], kinds=[c.kind for c in result.changes])


def replay_traced(out: Path, config: DetectorConfig, observations: pl.DataFrame | None = None) -> tuple:
    """(replay result, position score, matches) of OUT's observations under `config`."""
    with open(out / "trace.pkl", "rb") as file:
        trace = pickle.load(file)
    if observations is None:
        observations = pl.read_parquet(out / "tables" / "observations.parquet")
    prior = trace["priors"][0] if trace["priors"] else None
    result = replay(observations, config, prior)
    score, matches = score_replay_by_position(result, trace)
    return result, score, matches, trace


def main_replay(out: Path) -> None:
    result, score, matches, trace = replay_traced(out, DetectorConfig())
    names = _truth_by_id(trace["truth"])
    print(f"TP {score.tp} FP {score.fp} FN {score.fn}  fp {score.false_positive_ids} fn {score.false_negative_ids}")
    for change in result.changes:
        print(change.kind, change.session, change.object_id, change.partner_id, change.category, f"{change.score:.2f}")
    for m in matches:
        print("  ", m.reported.session, m.reported.object_id, "->", m.instance_id, names.get(m.instance_id), f"{m.distance_m * 100:.1f} cm")



def segments(recording: str, step: int, radius_m: float = 0.10) -> None:
    """Per true item of the recording's session: the segmentation's clusters near it (true poses,
    the objects' gate) over every `step`-th frame, by verdict (kept, or the test that rejected
    them), with their footprints: an item never kept is never an object."""
    from collections import Counter, defaultdict
    from dataclasses import replace

    from ndfa.eval.position_match import truth_items
    from ndfa.io.recording import RecordingReader
    from ndfa.perception import segmentation
    from ndfa.perception.segmentation_config import SegmentationConfig

    reader = RecordingReader(recording)
    truth = reader.ground_truth or {}
    session = truth.get("session", "target")
    names = _truth_by_id(truth)
    items = truth_items(truth, session)
    config = SegmentationConfig().for_objects()
    found: list = []
    original = segmentation._kept_clusters

    def kept_clusters(points, depths, cluster_of_point, plane_of_point, planes, up, camera, config):
        judged = original(points, depths, cluster_of_point, plane_of_point, planes, up, camera, config)
        found.extend((points[cluster_of_point == c].mean(axis=0), v) for c, v in judged)
        return judged

    segmentation._kept_clusters = kept_clusters
    per_item: dict = defaultdict(Counter)
    shapes: dict = defaultdict(list)
    for frame in reader.frames(step=step):
        true = frame.pose_world_camera_true if frame.pose_world_camera_true is not None else frame.pose_world_camera
        frame = replace(frame, pose_world_camera=true)
        found.clear()
        _, verdicts = segmentation.explain_frame(frame, config)
        # the final verdicts (hidden, cut) replace the gate's, in the same order
        for (center, _), verdict in zip(list(found), verdicts):
            xy = center[:2]
            distances = [float(np.linalg.norm(xy - p[:2])) for _, _, p in items]
            best = int(np.argmin(distances))
            if distances[best] > radius_m:
                continue
            item = items[best][0]
            reason = verdict.rejected or "kept"
            per_item[item][reason] += 1
            s = verdict.shape
            shapes[item].append(f"{frame.index}:{reason}:{s.length_m * 100:.0f}x{s.width_m * 100:.0f}x{s.top_m * 100:.0f}cm"
                                f"@{s.depth_m:.1f}m")
    segmentation._kept_clusters = original
    for item, _, xy in items:
        category, change = names.get(item, ("?", "?"))
        print(f"{item:5d} {category:7s} {change:9s} ({xy[0]:+.2f} {xy[1]:+.2f}) {dict(per_item[item])}")
        print("      ", " ".join(shapes[item][:14]))


if __name__ == "__main__":
    if sys.argv[1] == "segments":
        segments(sys.argv[2], int(sys.argv[3]))
    elif sys.argv[1] == "run":
        run(sys.argv[2], sys.argv[3], Path(sys.argv[4]), sys.argv[5:])
    else:
        main_replay(Path(sys.argv[2]))
