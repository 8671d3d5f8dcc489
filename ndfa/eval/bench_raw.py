"""`ndfa bench raw`: the whole raw pass (`ndfa detect` on recordings without masks or poses), per stage.

A raw recording costs more than the target pass `ndfa bench detect` times: each session's poses
are estimated by odometry and its up read from the planes before the pass, every frame is
segmented, the two sessions' scene clouds are aligned before the target pass, and the detector
estimates T_rel along the way. This times all of it, both sessions, the way `ndfa detect` runs it
(the stages overlapped in threads, no sinks), and gives each stage's wall time as ms per frame of
both sessions' frames; frames/s is both sessions' frames over the wall time of the whole run, the
rate to compare with the sensor's (30 frames/s).

With the stages overlapped, a stage's time is its own thread's (waits for the GIL and the cores
included), so the per-frame stages add up to more than the wall time. Speed figures of this module
are figures of the machine it ran on: compare rows of one run, not runs on different machines.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ndfa.eval.bench import machine

if TYPE_CHECKING:  # the NDF's torch loads only when a benchmark runs
    from ndfa.pipeline import PipelineConfig

# The stages, in the order the pass meets them: before the pass (per session), per frame, before the target pass.
RAW_STAGES = ("odometry", "up", "reading", "segmentation", "perception", "encoding", "detection", "registration",
              "scene alignment")


def raw_pass(source: Path, target: Path, config: PipelineConfig | None = None, threads: int = 1, frame_step: int = 1,
             overlap: bool = True) -> dict:
    """One `ndfa detect SOURCE TARGET` without sinks, timed: `stage_s` (seconds over the run, each
    stage of `RAW_STAGES`), `stage_ms` (the same per frame of both sessions), `wall_s`, `fps`
    (both sessions' frames / wall_s), `cpu_s` (this process's CPU time: the figure that another
    job's share of the cores does not change), `score` (TP, FP, FN; None without ground truth)."""
    import torch

    # torch, with the NDF: here and not at the top, so that `ndfa bench sim` runs without it
    from ndfa.eval.runs import score_detection
    from ndfa.pipeline import ChangeDetectionPipeline, PipelineConfig
    from ndfa.run.detect import RunOptions, run_detection

    torch.set_num_threads(threads)
    if config is None:
        config = PipelineConfig()
    config = dataclasses.replace(config, encoder=dataclasses.replace(config.encoder, threads=threads))
    pipeline = ChangeDetectionPipeline(config)  # the NDF loads before the clock starts, as `ndfa detect`'s does
    cpu_started, started = time.process_time(), time.perf_counter()
    result = run_detection(source, target, config, sinks=[], options=RunOptions(frame_step=frame_step),
                           pipeline=pipeline, overlap=overlap)
    wall_s = time.perf_counter() - started
    cpu_s = time.process_time() - cpu_started
    score_detection(result)
    stage_s = dict.fromkeys(RAW_STAGES, 0.0)
    for world in result.worlds.values():
        for stage, seconds in world.seconds.items():
            stage_s[stage] += seconds
    for totals in result.run.stage_totals.values():
        for stage, ms in totals.items():
            stage_s[stage] = stage_s.get(stage, 0.0) + ms / 1e3
    if result.alignment is not None:
        stage_s["scene alignment"] += result.alignment.seconds
    frames = sum(result.frames.values())
    score = result.score
    return {"frames": frames, "wall_s": wall_s, "fps": frames / wall_s, "cpu_s": cpu_s, "stage_s": stage_s,
            "stage_ms": {stage: seconds / max(frames, 1) * 1e3 for stage, seconds in stage_s.items()},
            "score": None if score is None else (score.tp, score.fp, score.fn),  # type: ignore[attr-defined]
            "registration": result.describe_registration(), "poses": [w.pose_source for w in result.worlds.values()],
            "stages": "at the same time" if overlap else "one after the other",
            "machine": machine()}


def raw_pass_runs(source: Path, target: Path, now: PipelineConfig | None = None, before: PipelineConfig | None = None,
                  compare: bool = False, load: bool = False, repeat: int = 1, threads: int = 1,
                  frame_step: int = 1) -> list[dict]:
    """`raw_pass` with the config `now` (default: the shipped one) `repeat` times, each row
    labelled; with `compare`, `before` (a `PipelineConfig`) alternating with it (before, now,
    before, now, ...: on a shared machine both see the same load), so that their ratio holds where
    the absolute figures do not. A label's row is its run of median frames/s, every run's in
    `fps_runs`. With `load`, now once more beside one busy process (`python -c 'while True: pass'`,
    started here and stopped after)."""
    runs: dict[str, list[dict]] = {"before": [], "now": []}
    for _ in range(repeat):
        if compare:
            runs["before"].append(raw_pass(source, target, before, threads, frame_step))
        runs["now"].append(raw_pass(source, target, now, threads, frame_step))
    rows = [{"label": label} | _median_run(label_runs) for label, label_runs in runs.items() if label_runs]
    if load:
        import subprocess
        import sys

        busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        try:
            rows.append({"label": "now, beside one busy process"} | raw_pass(source, target, now, threads, frame_step))
        finally:
            busy.kill()
            busy.wait()
    return rows


def _median_run(runs: list[dict]) -> dict:
    median = sorted(runs, key=lambda run: run["fps"])[(len(runs) - 1) // 2]
    return median | {"fps_runs": [run["fps"] for run in runs]}


def before_levers() -> PipelineConfig:
    """The `PipelineConfig` of the raw pass before the levers of 2026-12-03 afternoon (docs/speed.md),
    for `ndfa bench raw --compare`."""
    from ndfa.pipeline import PipelineConfig

    return PipelineConfig()
