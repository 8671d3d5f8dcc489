"""`ndfa bench sim`: per-stage timings of the synthetic pipeline on the `paper` scene.

Times each stage separately over the first frames of the source session: building the world,
ray casting, depth noise, writing a frame to MCAP and reading it back. Medians, in milliseconds.
"""

from __future__ import annotations

import dataclasses
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from ndfa.ingest.synthetic import SESSION_START, render_objects
from ndfa.recording import Frame, RecordingReader, RecordingWriter
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
                  machine=f"{platform.processor() or platform.machine()}, {_cpu_count()} cores")
    result["total_ms_per_frame"] = sum(result[f"{s}_ms"] for s in ("render", "noise", "write"))
    return result


def _cpu_count() -> int:
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def bench_ndf(weights: Path | None = None, repeats: int = 30, points: int = 1000, threads: int = 2) -> dict[str, float]:
    """Median milliseconds to encode one observation of `points` points, and a batch of 8, with
    center recovery and the reconstruction grid (the full `NDFEncoder.encode_batch`)."""
    import torch

    from ndfa.ndf.encoder import NDFEncoder

    torch.set_num_threads(threads)
    encoder = NDFEncoder(weights)
    rng = np.random.default_rng(0)
    clouds = [rng.normal(scale=0.03, size=(points, 3)) + [0.0, 0.0, 1.0] for _ in range(8)]
    poses = [np.eye(4)] * 8
    result = {}
    for name, count in (("one", 1), ("batch8", 8)):
        encoder.encode_batch(clouds[:count], poses[:count])  # warm-up
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            encoder.encode_batch(clouds[:count], poses[:count])
            times.append(time.perf_counter() - start)
        result[f"{name}_ms"] = float(np.median(times) * 1e3)
    result["batch8_ms_per_observation"] = result["batch8_ms"] / 8
    result.update(points=points, threads=threads, grid=encoder.config.grid_resolution,
                  machine=f"{platform.processor() or platform.machine()}, {_cpu_count()} cores")
    return result
