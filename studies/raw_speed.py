"""The measurements behind docs/speed.md's section of 2026-12-03 afternoon (issue 32): where the raw
pass's CPU goes, the levers tried, and what grows with a recording's length.

    python studies/raw_speed.py segmentation RAW_TARGET.mcap [STEP]   # cProfile of segment_frame (true poses)
    python studies/raw_speed.py alignment RAW_DIR                     # cProfile of the scene alignment (true poses)
    python studies/raw_speed.py stride MASKED_TARGET.mcap [STEP]      # segmentation recall and CPU, stride 2 vs 3
    python studies/raw_speed.py gate RAW_TARGET.mcap [STEP]           # the objectness gate on the coarse grid only
    python studies/raw_speed.py normals RAW_TARGET.mcap [STEP]        # right_angles at fewer query points
    python studies/raw_speed.py speedup RAW_TARGET.mcap [STEP] [REV]  # segment_frame now vs at git REV: CPU, masks
    python studies/raw_speed.py stages RAW_TARGET.mcap [STEP]         # segment_frame's CPU by function
    python studies/raw_speed.py tracking TARGET.mcap [PERIOD]         # planes tracked from frame to frame vs searched
    python studies/raw_speed.py growth MASKED_DIR                     # tracemalloc over a target pass
    python studies/raw_speed.py repeat SHORT_DIR LONG_DIR TIMES       # a long recording: the frames repeated
    python studies/raw_speed.py encoding RAW_TARGET.mcap [STEP] [WEIGHTS]  # segments' encoding: full vs as decisions need, batches
    python studies/raw_speed.py motion RECORDING.mcap...              # how far the camera moves from frame to frame
    python studies/raw_speed.py voxel MASKED_TARGET.mcap [STEP] [SIDE]  # DBSCAN on voxels of SIDE metres: recall, CPU
    python studies/raw_speed.py reduced MASKED_TARGET.mcap [STEP]     # stride 4 / the gate's normals at half the points: recall, CPU

Speed figures are CPU times (`time.process_time`): on a shared machine wall times measure the others.
"""

from __future__ import annotations

import cProfile
import dataclasses
import pstats
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ndfa.io.recording import RecordingReader, RecordingWriter
from ndfa.perception import objectness
from ndfa.perception.segmentation import PlaneTracker, segment_frame
from ndfa.perception.segmentation_config import SegmentationConfig


def true_posed(path: str, step: int) -> list:
    """The recording's frames (every `step`-th) on their true poses (a raw recording has none of its own)."""
    return [dataclasses.replace(f, pose_world_camera=f.pose_world_camera_true) for f in RecordingReader(path).frames(step=step)]


def segmentation(path: str, step: str = "8") -> None:
    frames = true_posed(path, int(step))
    started, profile = time.process_time(), cProfile.Profile()
    profile.enable()
    for frame in frames:
        segment_frame(frame, SegmentationConfig())
    profile.disable()
    print(f"{len(frames)} frames, {(time.process_time() - started) / len(frames) * 1e3:.1f} ms CPU per frame (profiled)")
    pstats.Stats(profile).sort_stats("tottime").print_stats(25)


def alignment(directory: str) -> None:
    from ndfa.run.align import registration_prior
    from ndfa.run.world import prepare_session

    readers = [RecordingReader(Path(directory) / f"{s}.mcap") for s in ("source", "target")]
    worlds = {s: prepare_session(r, s, up="z", poses="truth") for s, r in zip(("source", "target"), readers)}
    started, wall, profile = time.process_time(), time.perf_counter(), cProfile.Profile()
    profile.enable()
    result = registration_prior(readers[0], readers[1], worlds, "scene")
    profile.disable()
    print(f"CPU {time.process_time() - started:.1f} s, wall {time.perf_counter() - wall:.1f} s;",
          "none" if result is None else result.describe())
    pstats.Stats(profile).sort_stats("cumtime").print_stats(30)


def stride(path: str, step: str = "4") -> None:
    from ndfa.eval.segmentation import segmentation_recall

    frames = list(RecordingReader(path).frames(step=int(step)))
    configs = {"stride 2": SegmentationConfig(), "stride 3, min_cluster_points 13": SegmentationConfig(stride=3, min_cluster_points=13)}
    for label, config in list(configs.items()) * 2:  # twice, alternating: the CPU times' spread
        r = segmentation_recall(frames, config)
        print(f"{label}: recovered {r.recovered}/{r.observations} = {r.recall:.1%}, {r.segments} segments, "
              f"{r.spurious} spurious, {r.cpu_ms_per_frame:.1f} ms CPU per frame", flush=True)


def gate(path: str, step: str = "3") -> None:
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig

    pipeline = ChangeDetectionPipeline(PipelineConfig())
    encoder = pipeline.encoder
    v0, threshold = encoder.config.v0, pipeline.min_segment_occupancy
    decoded: list[np.ndarray] = []
    full_grid = encoder._grid_occupancy

    def keep(z, queries, points, full=True):  # noqa: ANN001, ANN202  (the encoder's own signature)
        occupancy = full_grid(z, queries, points, full)
        decoded.append(occupancy.copy())
        return occupancy

    encoder._grid_occupancy = keep  # type: ignore[method-assign]
    means = []
    for frame in true_posed(path, int(step)):
        observed = pipeline.perceive(dataclasses.replace(frame, instances=None))
        decoded.clear()
        pipeline.encode(observed, full_reconstruction=True)
        for occupancy in (np.concatenate(decoded) if decoded else []):
            coarse = occupancy[encoder._coarse]
            means.append([occupancy[occupancy > v0].mean() if (occupancy > v0).any() else 0.0,
                          coarse[coarse > v0].mean() if (coarse > v0).any() else 0.0])
    full_mean, coarse_mean = np.array(means).T
    differ = (full_mean >= threshold) != (coarse_mean >= threshold)
    print(f"{len(full_mean)} segments: gate passed {int((full_mean >= threshold).sum())} (full grid), "
          f"{int((coarse_mean >= threshold).sum())} (coarse); {int(differ.sum())} decided differently")
    d = coarse_mean - full_mean
    print(f"coarse - full: median {np.median(d):.3f}, 5th/95th percentile {np.percentile(d, 5):.3f}/"
          f"{np.percentile(d, 95):.3f}, largest {np.abs(d).max():.3f}")
    for margin in (0.01, 0.02, 0.03, 0.05):
        near = np.abs(coarse_mean - threshold) < margin
        print(f"full grid only within {margin} of the gate: {near.mean():.1%} decoded in full, "
              f"{int((differ & ~near).sum())} decided differently")


def normals(path: str, step: str = "4") -> None:
    clusters = []
    measured = objectness.right_angles

    def keep(heights, flat, neighbours=24):  # noqa: ANN001, ANN202
        clusters.append((heights.copy(), flat.copy(), neighbours))
        return measured(heights, flat, neighbours)

    objectness.right_angles = keep  # type: ignore[assignment]
    for frame in true_posed(path, int(step)):
        segment_frame(frame, SegmentationConfig())
    objectness.right_angles = measured  # type: ignore[assignment]
    sizes = [len(c[0]) for c in clusters]
    print(f"{len(clusters)} clusters measured, {np.median(sizes):.0f} points (median), {max(sizes)} at most")
    reference = [measured(*c) for c in clusters]
    for most in (100_000, 400, 200, 100):
        started = time.process_time()
        values = [_right_angles_at(*c, most) for c in clusters]
        cpu_ms = (time.process_time() - started) / len(clusters) * 1e3
        both = [(a, b) for a, b in zip(values, reference) if a is not None and b is not None]
        changed = sum((a is None) != (b is None) or (a is not None and b is not None and (a > 0.5) != (b > 0.5))
                      for a, b in zip(values, reference))
        print(f"at most {most} query points: {cpu_ms:.2f} ms CPU per cluster, values within "
              f"{max(abs(a - b) for a, b in both):.3f}, {changed} verdicts changed")


def _right_angles_at(heights: np.ndarray, flat: np.ndarray, neighbours: int, most: int) -> float | None:
    """`objectness.right_angles` with the normals estimated at no more than `most` evenly spaced points."""
    points = np.column_stack([flat, heights])
    if len(points) <= neighbours:
        return None
    query = points[np.linspace(0, len(points) - 1, most).astype(int)] if len(points) > most else points
    _, nearest = cKDTree(points).query(query, neighbours)
    local = points[nearest] - points[nearest].mean(axis=1, keepdims=True)
    normal = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]
    wall = np.abs(normal[:, 2]) < 0.4
    if wall.sum() < 10:
        return None
    return float(np.abs(np.mean(np.exp(4j * np.arctan2(normal[wall, 1], normal[wall, 0])))))


def speedup(path: str, step: str = "4", rev: str = "7eea446") -> None:
    """`segment_frame` of this tree against the one of git revision `rev` (its ndfa/perception
    imported as a package of its own), alternating on the same frames (true poses): process CPU
    per frame of each, and whether the masks are the same."""
    import importlib
    import subprocess
    import tempfile

    package = Path(tempfile.mkdtemp()) / "before_perception"
    package.mkdir()
    listed = subprocess.run(["git", "ls-tree", "--name-only", rev, "ndfa/perception/"], capture_output=True,
                            text=True, check=True).stdout.split()
    for name in listed:
        text = subprocess.run(["git", "show", f"{rev}:{name}"], capture_output=True, text=True, check=True).stdout
        (package / Path(name).name).write_text(text.replace("ndfa.perception.", "before_perception."))
    sys.path.insert(0, str(package.parent))
    before = importlib.import_module("before_perception.segmentation")
    frames = true_posed(path, int(step))
    runs = {f"before ({rev})": lambda f, _: before.segment_frame(f), "now": lambda f, _: segment_frame(f)}
    if step == "1":  # consecutive frames: also with the planes tracked (PlaneTracker, a full search every 10)
        runs["now, planes tracked"] = lambda f, tracker: segment_frame(f, SegmentationConfig(), tracker)
    cpu: dict[str, list[float]] = {label: [] for label in runs}
    masks: dict[str, list[np.ndarray]] = {}
    for _ in range(3):  # alternating: all see the same load
        for label, run in runs.items():
            tracker = PlaneTracker(10)
            started = time.process_time()
            masks[label] = [run(frame, tracker) for frame in frames]
            cpu[label].append((time.process_time() - started) / len(frames) * 1e3)
    for label, values in cpu.items():
        print(f"{label}: {np.median(values):.1f} ms CPU per frame (median of 3; {min(values):.1f}-{max(values):.1f})")
    if "now, planes tracked" in masks:
        tracked = masks.pop("now, planes tracked")
        moved = sum(not np.array_equal(a, b) for a, b in zip(masks["now"], tracked))
        print(f"planes tracked: masks differ from the full search's in {moved} of {len(frames)} frames")
    old, new = masks.values()
    differ = [i for i, (a, b) in enumerate(zip(old, new)) if not np.array_equal(a, b)]
    pixels = sum(int((a != b).sum()) for a, b in zip(old, new))
    segments = [sum(len(np.unique(m)) - 1 for m in ms) for ms in (old, new)]
    print(f"{len(frames)} frames: masks differ in {len(differ)} ({pixels} pixels); segments {segments[0]} -> {segments[1]}")


def stages(path: str, step: str = "4") -> None:
    """`segment_frame`'s process CPU by function (each wrapped in a timer; nested ones count in
    their callers too), on the recording's true poses."""
    from collections import defaultdict

    from ndfa.perception import objectness as gate
    from ndfa.perception import segmentation as module

    spent: dict[str, float] = defaultdict(float)

    def timed(owner: object, name: str) -> None:
        function = getattr(owner, name)

        def wrapper(*args: object, **kwargs: object) -> object:
            started = time.process_time()
            try:
                return function(*args, **kwargs)
            finally:
                spent[name] += time.process_time() - started

        setattr(owner, name, wrapper)

    for name in ("find_horizontal_planes", "_candidates", "_under_tall", "dbscan", "voxel_dbscan", "_kept_clusters", "_hidden_above",
                 "_fill", "_world_points"):
        timed(module, name)
    for name in ("right_angles", "lean"):
        timed(gate, name)
    frames = true_posed(path, int(step))
    started = time.process_time()
    for frame in frames:
        module.segment_frame(frame)
    total = time.process_time() - started
    print(f"{len(frames)} frames, {total / len(frames) * 1e3:.1f} ms CPU per frame (timed)")
    for name, seconds in sorted(spent.items(), key=lambda item: -item[1]):
        print(f"  {name}: {seconds / len(frames) * 1e3:.2f} ms ({seconds / total:.0%})")


def tracking(path: str, period: str = "10") -> None:
    """Planes tracked from frame to frame (`PlaneTracker`, a full search every `period` frames)
    against a full search in every frame: `segment_frame` on every frame (true poses), alternating,
    process CPU per frame, the masks' differences; with a masked recording also the segmentation
    recall of both."""
    from ndfa.eval import segmentation as evaluation

    frames = true_posed(path, 1)
    config = SegmentationConfig()
    trackers: dict[str, PlaneTracker | None] = {}
    cpu: dict[str, list[float]] = {"full search": [], f"tracked, full search every {period}": []}
    masks: dict[str, list[np.ndarray]] = {}
    for _ in range(3):
        for label in cpu:
            tracker = trackers[label] = PlaneTracker(int(period)) if label != "full search" else None
            started = time.process_time()
            masks[label] = [segment_frame(frame, config, tracker) for frame in frames]
            cpu[label].append((time.process_time() - started) / len(frames) * 1e3)
    for label, values in cpu.items():
        tracker = trackers[label]
        searched = "" if tracker is None else f"; full searches in {tracker.searches} of {tracker.frames} frames"
        print(f"{label}: {np.median(values):.1f} ms CPU per frame (median of 3; {min(values):.1f}-{max(values):.1f})"
              f"{searched}")
    old, new = masks.values()
    differ = sum(not np.array_equal(a, b) for a, b in zip(old, new))
    pixels = sum(int((a != b).sum()) for a, b in zip(old, new))
    print(f"masks differ in {differ} of {len(frames)} frames ({pixels} pixels)")
    if frames[0].instances is not None:
        for label in cpu:  # segmentation_recall segments the frames in order: the tracker sees them so
            tracker = PlaneTracker(int(period)) if label != "full search" else None
            setattr(evaluation, "segment_frame", lambda frame, config, t=tracker: segment_frame(frame, config, t))
            r = evaluation.segmentation_recall(frames, config)
            print(f"{label}: recovered {r.recovered}/{r.observations} = {r.recall:.1%}, {r.segments} segments, "
                  f"{r.spurious} spurious")
        setattr(evaluation, "segment_frame", segment_frame)


def growth(directory: str) -> None:
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
    from ndfa.run.detect import run_detection

    snapshots = {}

    def on_frame(session: str, done: int, total: int) -> None:
        if session == "target" and done in (total // 4, total - 1):
            snapshots[done] = tracemalloc.take_snapshot()
            print(f"target frame {done}: {tracemalloc.get_traced_memory()[0] / 1e6:.2f} MB traced", flush=True)

    pipeline = ChangeDetectionPipeline(PipelineConfig())
    tracemalloc.start(8)
    result = run_detection(Path(directory) / "source.mcap", Path(directory) / "target.mcap", pipeline.config,
                           sinks=[], on_frame=on_frame, pipeline=pipeline, overlap=False)
    first, last = (snapshots[k] for k in sorted(snapshots))
    for stat in last.compare_to(first, "traceback")[:8]:
        print(stat, *stat.traceback.format()[-4:], sep="\n    ")
    print(f"decisions kept: {len(result.pair.decisions)}; most measurements of an object: "
          f"{max(int(v.max()) for v in result.object_measurements.values())}")


def repeat(short: str, long: str, times: str) -> None:
    """LONG/{source,target}.mcap: SHORT's frames `times` times over, renumbered, timestamps continued."""
    Path(long).mkdir(parents=True, exist_ok=True)
    for session in ("source", "target"):
        reader = RecordingReader(Path(short) / f"{session}.mcap")
        first, second = reader.frames(stop=2)
        interval, count = second.timestamp - first.timestamp, len(reader)
        meta = {k: v for k, v in reader.meta.items() if k not in ("format", "format_version", "depth_scale", "units")}
        partial = Path(long) / f".{session}.mcap.partial"
        with RecordingWriter(partial, meta) as writer:
            if reader.ground_truth is not None:
                writer.write_ground_truth(reader.ground_truth)
            for lap in range(int(times)):
                for frame in reader.frames():
                    index = lap * count + frame.index
                    writer.write_frame(dataclasses.replace(frame, index=index, timestamp=first.timestamp + index * interval))
        partial.rename(Path(long) / f"{session}.mcap")
        print(f"{session}: {count * int(times)} frames")


def encoding(path: str, step: str = "2", weights: str = "") -> None:
    """The encoding of a raw recording's segments (true poses; `weights` a checkpoint, default the
    shipped one): process CPU per frame with the reconstructions decoded in full and only as far
    as emptiness, alternating, and whether emptiness, categories and centers agree; the segments'
    mean occupancy against the gate's bar; and frames encoded 1, 2 or 4 to a call."""
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig

    frames = true_posed(path, int(step))
    pipeline = ChangeDetectionPipeline(PipelineConfig(weights=Path(weights) if weights else None))
    observed = [pipeline.perceive(frame) for frame in frames]
    views = [(o.points_camera, f.frame.pose_world_camera) for f in observed for o in f.observations]
    print(f"{len(frames)} frames, {len(views)} segments; gate {pipeline.gate}, bar {pipeline.min_segment_occupancy}")

    def encoded(group: int, full: bool) -> list:
        codes = []
        for start in range(0, len(observed), group):
            batch = [(o.points_camera, f.frame.pose_world_camera) for f in observed[start:start + group] for o in f.observations]
            codes += pipeline.encoder.encode_batch([c for c, _ in batch], [p for _, p in batch], full)
        return codes

    runs = {"full, 1 frame a call": (1, True), "as far as emptiness": (1, False), "full, 2 frames a call": (2, True),
            "full, 4 frames a call": (4, True)}
    cpu: dict[str, list[float]] = {label: [] for label in runs}
    codes = {}
    for _ in range(3):  # alternating: all see the same load
        for label, (group, full) in runs.items():
            started = time.process_time()
            codes[label] = encoded(group, full)
            cpu[label].append((time.process_time() - started) / len(frames) * 1e3)
    for label, values in cpu.items():
        print(f"{label}: {np.median(values):.2f} ms CPU per frame (median of 3; {min(values):.2f}-{max(values):.2f})")
    full, partial = codes["full, 1 frame a call"], codes["as far as emptiness"]
    print("as far as emptiness vs full: emptiness agrees", sum((a.mean_occupancy > 0) == (b.mean_occupancy > 0)
                                                               for a, b in zip(full, partial)),
          f"of {len(full)}, categories", sum(a.category == b.category for a, b in zip(full, partial)),
          ", centers apart at most", max(float(np.abs(a.center_world - b.center_world).max()) for a, b in zip(full, partial)))
    occupancy = np.array([c.mean_occupancy for c in full])
    bar = pipeline.min_segment_occupancy
    print(f"mean occupancy: empty {int((occupancy <= 0).sum())}, under the bar {int(((occupancy > 0) & (occupancy < bar)).sum())}, "
          f"within 0.05 of it {int((np.abs(occupancy - bar) < 0.05).sum())}; median {np.median(occupancy):.3f}")


def motion(*paths: str) -> None:
    """The camera's motion from one frame to the next (true poses where the recording has them):
    translation and rotation percentiles, and the share of frames that moved less than 1 cm and 1
    degree (the frames whose segmentation the previous frame's could stand for)."""
    for path in paths:
        poses = [f.pose_world_camera_true if f.pose_world_camera_true is not None else f.pose_world_camera
                 for f in RecordingReader(path).frames()]
        moved = np.array([np.linalg.norm(a[:3, 3] - b[:3, 3]) for a, b in zip(poses, poses[1:])])
        turned = np.degrees(np.arccos(np.clip([(np.trace(a[:3, :3].T @ b[:3, :3]) - 1) / 2 for a, b in zip(poses, poses[1:])],
                                              -1.0, 1.0)))
        still = (moved < 0.01) & (turned < 1.0)
        print(f"{path}: {len(poses)} frames; cm p10/50/90 {np.round(np.percentile(moved * 100, [10, 50, 90]), 2)}, "
              f"degrees {np.round(np.percentile(turned, [10, 50, 90]), 2)}; under 1 cm and 1 degree: {still.mean():.0%}")


def voxel(path: str, step: str = "4", side: str = "0.0125") -> None:
    """DBSCAN on voxels of `side` metres (`SegmentationConfig.dbscan_voxel_m`, the default 0.01 since
    seg35) against the exact one (0), alternating, on a masked recording: the segmentation's recall
    of the mug views and its spurious segments, and `segment_frame`'s process CPU per frame."""
    from ndfa.eval.segmentation import segmentation_recall

    frames = list(RecordingReader(path).frames(step=int(step)))
    variants = {"exact DBSCAN": SegmentationConfig(dbscan_voxel_m=0.0),
                f"DBSCAN on {side} m voxels": SegmentationConfig(dbscan_voxel_m=float(side))}
    cpu: dict[str, list[float]] = {label: [] for label in variants}
    for _ in range(3):
        for label, config in variants.items():
            cpu[label].append(segmentation_recall(frames, config).cpu_ms_per_frame)
    for label, values in cpu.items():
        r = segmentation_recall(frames, variants[label])
        print(f"{label}: recovered {r.recovered}/{r.observations} = {r.recall:.1%}, {r.segments} segments, "
              f"{r.spurious} spurious; {np.median(values):.1f} ms CPU per frame (median of 3; {min(values):.1f}-{max(values):.1f})")


def reduced(path: str, step: str = "4") -> None:
    """The segmentation at a coarser sample grid against the default, alternating, on a masked
    recording (issue 32; seg35): every 4th pixel in both directions instead of every 2nd (the plane
    search, the candidates, DBSCAN and the gate's normals on a quarter of the samples; the masks
    painted back at full resolution as at stride 2; the sample counts' thresholds a quarter; also with
    the gate's normals and DBSCAN's radius widened for the sparser samples), and stride 2 with the gate's normals estimated at every 2nd point of a cluster (neighbours from
    all). The segmentation's recall of the mug views, its spurious segments, process CPU per frame."""
    from ndfa.eval.segmentation import segmentation_recall

    frames = list(RecordingReader(path).frames(step=int(step)))
    measured = objectness.right_angles
    variants = {"stride 2 (default)": (SegmentationConfig(), measured),
                "stride 4, min_cluster_points 8, min_plane_points 75":
                    (SegmentationConfig(stride=4, min_cluster_points=8, min_plane_points=75), measured),
                "the same, and the gate's normals from 8 neighbours, DBSCAN's eps 4 cm":
                    (SegmentationConfig(stride=4, min_cluster_points=8, min_plane_points=75, dbscan_eps_m=0.04,
                                        objectness=dataclasses.replace(objectness.ObjectnessConfig(), normal_neighbours=8)),
                     measured),
                "stride 2, the gate's normals at every 2nd point": (SegmentationConfig(), _right_angles_halved)}
    cpu: dict[str, list[float]] = {label: [] for label in variants}
    results = {}
    try:
        for _ in range(3):  # alternating: all see the same load
            for label, (config, normals) in variants.items():
                objectness.right_angles = normals
                results[label] = segmentation_recall(frames, config)
                cpu[label].append(results[label].cpu_ms_per_frame)
    finally:
        objectness.right_angles = measured
    for label, r in results.items():
        values = cpu[label]
        print(f"{label}: recovered {r.recovered}/{r.observations} = {r.recall:.1%}, {r.segments} segments, "
              f"{r.spurious} spurious; {np.median(values):.1f} ms CPU per frame (median of 3; {min(values):.1f}-{max(values):.1f})")


def _right_angles_halved(heights: np.ndarray, flat: np.ndarray, neighbours: int = 24) -> float | None:
    """`objectness.right_angles` with the normals estimated at every 2nd point (neighbours from all)."""
    points = np.column_stack([flat, heights])
    if len(points) <= neighbours:
        return None
    points = points - points.mean(axis=0)
    _, nearest = cKDTree(points).query(points[::2], neighbours)
    normals = objectness._least_axes(*(points[:, axis][nearest] for axis in range(3)))
    wall = np.abs(normals[:, 2]) < 0.4
    if wall.sum() < 10:
        return None
    return float(np.abs(np.mean(np.exp(4j * np.arctan2(normals[wall, 1], normals[wall, 0])))))


if __name__ == "__main__":
    commands = {f.__name__: f for f in (segmentation, alignment, stride, gate, normals, speedup, stages, tracking, growth, repeat,
                                        encoding, motion, voxel, reduced)}
    if len(sys.argv) < 2 or sys.argv[1] not in commands:
        sys.exit(__doc__)
    commands[sys.argv[1]](*sys.argv[2:])
