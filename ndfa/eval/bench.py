"""`ndfa bench sim`: per-stage timings of the synthetic pipeline on the `paper` scene.

Times each stage separately over the first frames of the source session: building the world,
ray casting, depth noise, writing a frame to MCAP and reading it back. Medians, in milliseconds.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from ndfa.change.associate import Measurement
from ndfa.change.detector import ChangeDetector
from ndfa.eval.revision import alternate, beside_busy_process, revision_tree, run_in_tree
from ndfa.io.ingest.synthetic import SESSION_START, render_objects
from ndfa.io.recording import Frame, RecordingReader, RecordingWriter
from ndfa.sim.presets import make_config
from ndfa.sim.render import SceneRenderer
from ndfa.sim.trajectory import camera_poses
from ndfa.sim.world import build_world, procedural_models


def bench_sim(frames: int = 60, preset: str = "paper", seed: int = 0) -> dict[str, float]:
    """Median milliseconds per stage (per frame for the per-frame stages) and the machine."""
    timings: dict[str, list[float]] = {k: [] for k in ("render", "noise", "write", "read")}

    start = time.perf_counter()
    config = make_config(preset, seed)
    world = build_world(config, procedural_models(config))
    world_ms = (time.perf_counter() - start) * 1e3
    renderer = SceneRenderer(render_objects(world, "source"))
    trajectory = dataclasses.replace(config.trajectory, route=config.source_route)
    poses = camera_poses(world.tables, trajectory, np.random.default_rng(0))[:frames]
    rng = np.random.default_rng(0)
    renderer.render(config.camera, poses[0])  # the first cast builds the ray-tracing structure

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.mcap"
        with RecordingWriter(path, {"source": "bench", "session": "source"}) as writer:
            for index, pose in enumerate(poses):
                t0 = time.perf_counter()
                view = renderer.render(config.camera, pose)
                t1 = time.perf_counter()
                depth = config.depth_noise.apply(view.depth, view.normals_camera, rng, config.camera)
                t2 = time.perf_counter()
                writer.write_frame(Frame(index, SESSION_START["source"] + index, view.rgb, depth,
                                         config.camera.K, pose, view.instance))
                t3 = time.perf_counter()
                timings["render"].append(t1 - t0)
                timings["noise"].append(t2 - t1)
                timings["write"].append(t3 - t2)
        reader = RecordingReader(path)
        t_last = time.perf_counter()
        for _ in reader.frames():
            now = time.perf_counter()
            timings["read"].append(now - t_last)
            t_last = now

    result = {f"{stage}_ms": float(np.median(values) * 1e3) for stage, values in timings.items()}
    result.update(world_ms=world_ms, frames=len(poses), triangles=renderer.triangle_count,
                  width=config.camera.width, height=config.camera.height,
                  machine=machine())
    result["total_ms_per_frame"] = sum(result[f"{s}_ms"] for s in ("render", "noise", "write"))
    return result


def machine() -> str:
    """The processor and the cores this process may use, as the benchmarks' tables name the machine."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return f"{platform.processor() or platform.machine()}, {cores} cores"


def bench_ndf(weights: Path | None = None, repeats: int = 30, points: int = 1000, threads: int = 2) -> dict[str, float]:
    """Median milliseconds to encode one observation of `points` points, and a batch of 8:
    shape code and center from the head alone (`head_*`), then the full `NDFEncoder.encode_batch`
    with the reconstruction grid at the encoder's default resolution and at the detector's 12^3."""
    import torch

    # torch, with the NDF: here and not at the top, so that `ndfa bench sim` and `scaling` run without it
    from ndfa.ndf.encoder import FINE_GRID_RESOLUTION, EncoderConfig, NDFEncoder

    torch.set_num_threads(threads)
    encoders = {"": NDFEncoder(weights, EncoderConfig(grid_resolution=FINE_GRID_RESOLUTION)), "grid12_": NDFEncoder(weights)}
    model = encoders[""].model
    rng = np.random.default_rng(0)
    clouds = [rng.normal(scale=0.03, size=(points, 3)) + [0.0, 0.0, 1.0] for _ in range(8)]
    poses = [np.eye(4)] * 8

    @torch.inference_mode()
    def head_only(count: int) -> None:  # what the center and code need: resample, centre, encode, heads
        cloud = np.stack([encoders[""].resample(c) for c in clouds[:count]])
        z = encoders[""].latent(cloud, poses[:count])[0]
        model.shape_code(z), model.center_offset(z)

    def median_ms(run) -> float:
        run()  # warm-up
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            run()
            times.append(time.perf_counter() - start)
        return float(np.median(times) * 1e3)

    result = {}
    for name, count in (("one", 1), ("batch8", 8)):
        result[f"head_{name}_ms"] = median_ms(lambda: head_only(count))
        for prefix, encoder in encoders.items():
            result[f"{prefix}{name}_ms"] = median_ms(lambda: encoder.encode_batch(clouds[:count], poses[:count]))
    for prefix in ("head_", "", "grid12_"):
        result[f"{prefix}batch8_ms_per_observation"] = result[f"{prefix}batch8_ms"] / 8
    result.update(points=points, threads=threads, grid=encoders[""].config.grid_resolution,
                  machine=machine())
    return result


def bench_detect(source: Path, target: Path, threads: int = 1, frame_step: int = 1, runtime: str = "auto",
                 weights: Path | None = None, full_reconstruction: bool = False, overlap: bool = True,
                 n_points: int | None = None, knn: int | None = None, reuse_angle_deg: float = 0.0) -> dict:
    """The whole target pass without sinks: frames per second, and ms per frame of each stage.
    `threads`: torch's and ONNX Runtime's; `runtime`: the NDF's (`ndfa.ndf.runtime`); `weights`:
    the NDF's (default: the shipped ones); `full_reconstruction`: decode every reconstruction, as a
    run with sinks does; `overlap`: the stages run at the same time (`ndfa.run.detect.staged`): a
    stage's ms are then its own thread's time, and the frame's wall time is less than their sum
    (reading is timed in the perception thread); `reuse_angle_deg`: `ReuseConfig.angle_deg` (0: off)."""
    import torch

    # torch, with the NDF: here and not at the top, so that `ndfa bench sim` and `scaling` run without it
    from ndfa.eval.runs import score_detection
    from ndfa.ndf.encoder import EncoderConfig
    from ndfa.ndf.reuse import ReuseConfig
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
    from ndfa.run.detect import RunOptions, run_detection

    torch.set_num_threads(threads)
    config = PipelineConfig(encoder=EncoderConfig(runtime=runtime, threads=threads, n_points=n_points, knn=knn), weights=weights,
                            reuse=ReuseConfig(angle_deg=reuse_angle_deg))
    pipeline = ChangeDetectionPipeline(config)
    cpu_started = time.process_time()
    result = score_detection(run_detection(source, target, config, sinks=[], options=RunOptions(frame_step=frame_step),
                                           pipeline=pipeline, full_reconstruction=full_reconstruction, overlap=overlap))
    per_frame_ms = result.seconds["target"] / result.frames["target"] * 1e3
    stages = dict(result.stage_ms)
    return {"fps": result.target_fps, "frames": result.frames["target"], "total_ms": per_frame_ms,
            "stage_ms": stages, "threads": threads, "runtime": pipeline.encoder.runtime.name,
            "weights": "shipped" if weights is None else str(weights),
            "points": pipeline.encoder.n_points, "neighbours": pipeline.encoder.model.encoder.knn,
            "reuse_angle_deg": reuse_angle_deg,
            "reconstruction": "full" if full_reconstruction else "as decisions need",
            "stages": "at the same time" if overlap else "one after the other",
            "cpu_s": time.process_time() - cpu_started,  # both passes, this process's CPU time
            "score": None if result.score is None else (result.score.tp, result.score.fp, result.score.fn),
            "machine": machine()}


# Run in a child process by `bench_detect_of`, in an older revision's tree: that revision's `bench_detect`.
_BENCH_DETECT_CHILD = """
import json, sys
from pathlib import Path
from ndfa.eval.bench import bench_detect
source, target, threads, frame_step, runtime, weights, overlap, out = sys.argv[1:]
row = bench_detect(Path(source), Path(target), threads=int(threads), frame_step=int(frame_step), runtime=runtime,
                   weights=Path(weights) if weights else None, overlap=overlap == "1")
Path(out).write_text(json.dumps(row))
"""


def bench_detect_of(tree: Path, ref: str, source: Path, target: Path, threads: int = 1, frame_step: int = 1,
                    runtime: str = "auto", weights: Path | None = None, overlap: bool = True) -> dict:
    """`bench_detect` (reconstructions as decisions need) as the code of git revision `ref` of this
    checkout runs it: its files in `tree` (`ndfa.eval.revision.revision_tree`), its `bench_detect`
    in a child process; `weights` None: that revision's shipped ones. The row is the child's, its
    timings taken inside the child as here (the child's start is not in them), with `ref`."""
    out = tree / "bench_detect.json"
    run_in_tree(tree, ref, ["-c", _BENCH_DETECT_CHILD, str(source.resolve()), str(target.resolve()), str(threads),
                            str(frame_step), runtime, "" if weights is None else str(weights.resolve()),
                            "1" if overlap else "0", str(out)], "bench_detect")
    row = json.loads(out.read_text())
    return row | {"ref": ref, "score": None if row["score"] is None else tuple(row["score"])}


def bench_detect_runs(source: Path, target: Path, threads: int = 1, compare: bool = False, load: bool = False,
                      frame_step: int = 1, runtime: str = "auto", weights: Path | None = None,
                      before_runtime: str | None = None, before_weights: Path | None = None,
                      overlap: bool = True, repeat: int = 1, n_points: int | None = None,
                      knn: int | None = None, reuse_angle_deg: float = 0.0, before_ref: str | None = None) -> list[dict]:
    """`bench_detect` back to back, each row labelled: "now" (`weights`, default the shipped ones,
    on `runtime`) `repeat` times, its row the run of median frames/s with every run's in
    `fps_runs` (the overlapping stages vary from run to run). With `compare`, a "before" in turns
    with now (`ndfa.eval.revision.alternate`: before, now, before, now, ...), also `repeat` times:
    without `before_ref`, this code as the pass ran before: `before_runtime` (default torch) with
    `before_weights` (default the shipped ones), every reconstruction decoded, the stages one after
    the other; with `before_ref`, the code of that git revision of this checkout
    (`bench_detect_of`) with `before_runtime` (default `runtime`), `before_weights` (default that
    revision's shipped ones) and `overlap` as now's. With `load`, "now" once more beside one busy
    process (`ndfa.eval.revision.beside_busy_process`). `n_points`, `knn`: the encoder's now
    (`EncoderConfig`; None: the checkpoint's); `reuse_angle_deg`: now's `ReuseConfig.angle_deg`."""
    settings = {"overlap": overlap, "n_points": n_points, "knn": knn, "reuse_angle_deg": reuse_angle_deg}
    now = functools.partial(bench_detect, source, target, threads, frame_step, runtime, weights, **settings)
    with contextlib.ExitStack() as stack:
        before = None
        if compare and before_ref is not None:
            tree = stack.enter_context(revision_tree(before_ref))
            before = functools.partial(bench_detect_of, tree, before_ref, source, target, threads, frame_step,
                                       before_runtime or runtime, before_weights, overlap)
        elif compare:
            before = functools.partial(bench_detect, source, target, threads, frame_step, before_runtime or "torch",
                                       before_weights, full_reconstruction=True, overlap=False)
        rows = alternate(now, before, repeat)
    if load:
        rows.append({"label": "beside one busy process"} | beside_busy_process(now))
    return rows


def bench_detection_scaling(sizes: tuple[int, ...] = (40, 100, 1000, 10_000), frames: int = 50,
                            per_frame: int = 4, seed: int = 0) -> list[dict]:
    """ms per target frame of the detection step alone (tree, association, graphs) with maps of
    `size` objects: mugs in groups of four on tables 1.5 m apart, the target revisiting them."""
    rows = []
    for size in sizes:
        rng = np.random.default_rng(seed)
        tables = int(np.ceil(size / 4))
        side = int(np.ceil(np.sqrt(tables)))
        centers = np.array([[1.5 * (t % side), 1.5 * (t // side), 0.8] for t in range(tables)])
        offsets = np.array([[-0.2, -0.15, 0], [0.2, -0.1, 0], [-0.15, 0.2, 0], [0.25, 0.2, 0]])
        positions = (centers[:, None] + offsets[None]).reshape(-1, 3)[:size]
        codes = rng.normal(size=(size, 32))
        detector = ChangeDetector()
        for start in range(0, size, per_frame):
            detector.add_source([Measurement(start, i, codes[i], positions[i], 0.5) for i in range(start, min(start + per_frame, size))])

        def frame(index, start):
            ids = range(start, min(start + per_frame, size))
            return [Measurement(index, i, codes[i] + rng.normal(scale=0.02, size=32),
                                positions[i] + rng.normal(scale=0.004, size=3), 0.6) for i in ids]

        for k in range(4):  # enough objects to register
            detector.add_target(frame(k, 4 * k % size))
        times = []
        for k in range(frames):
            measurements = frame(100 + k, int(rng.integers(0, max(size // per_frame, 1))) * per_frame)
            start = time.perf_counter()
            detector.add_target(measurements)
            times.append(time.perf_counter() - start)
        rows.append({"objects": size, "ms_per_frame": float(np.median(times) * 1e3),
                     "registered": detector.registration is not None})
    return rows
