"""`ndfa bench raw`: the whole raw pass (`ndfa detect` on recordings without masks or poses), per stage.

A raw recording costs more than the target pass `ndfa bench detect` times: each session's poses
are estimated by odometry and its up read from the planes before the pass, every frame is
segmented, the two sessions' scene clouds are aligned before the target pass, and the detector
estimates T_rel along the way. This times all of it, both sessions, the way `ndfa detect` runs it
(the stages overlapped in threads, no sinks), and gives each stage's wall time as ms per input frame
(both sessions' frames, those a `--frame-step` or `--rate` skips counted too); frames/s is both
sessions' input frames over the wall time of the whole run; `realtime`, the time both sessions took to
record over that wall time (`ndfa.run.rate.recorded_seconds`): above 1 the run kept up with the
camera. A run that skips frames says how many it used (`frames_used`).

With the stages overlapped, a stage's time is its own thread's (waits for the GIL and the cores
included), so the per-frame stages add up to more than the wall time. Speed figures of this module
are figures of the machine it ran on: compare rows of one run, not runs on different machines.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING

from ndfa.eval.bench import machine
from ndfa.eval.revision import alternate, beside_busy_process, revision_tree, run_in_tree
from ndfa.io.recording import RecordingReader
from ndfa.run.rate import DEFAULT_RATE_HZ, recorded_seconds

if TYPE_CHECKING:  # the NDF's torch loads only when a benchmark runs
    from ndfa.pipeline import PipelineConfig

# The stages, in the order the pass meets them: before the pass (per session), per frame, before the target pass.
RAW_STAGES = ("odometry", "up", "reading", "segmentation", "perception", "encoding", "detection", "registration",
              "scene alignment")


def raw_pass(source: Path, target: Path, config: PipelineConfig | None = None, threads: int = 1, frame_step: int = 1,
             overlap: bool = True, workers: int | None = None, rate_hz: float | None = DEFAULT_RATE_HZ) -> dict:
    """One `ndfa detect SOURCE TARGET` without sinks, timed: `stage_s` (seconds over the run, each
    stage of `RAW_STAGES`, wherever it ran: the worker's stages come back with their results,
    `ndfa.run.workers`), `stage_ms` (the same per input frame of both sessions), `wall_s`, `fps` (both
    sessions' input frames / wall_s; `frames_used` those the run used), `cpu_s` (the CPU time of this process and of the worker processes it
    waited for: the figure that another job's share of the cores does not change), `score` (TP, FP,
    FN; None without ground truth)."""
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
    cpu_started, started = _cpu_s(), time.perf_counter()
    options = RunOptions(frame_step=frame_step, rate_hz=rate_hz, **({} if workers is None else {"workers": workers}))
    result = run_detection(source, target, config, sinks=[], options=options, pipeline=pipeline, overlap=overlap)
    wall_s = time.perf_counter() - started
    cpu_s = _cpu_s() - cpu_started
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
    frames = sum(len(reader) for reader in result.run.readers)  # input frames, the skipped ones too
    score = result.score
    return {"frames": frames, "frames_used": sum(result.frames.values()), "wall_s": wall_s, "fps": frames / wall_s, "cpu_s": cpu_s, "stage_s": stage_s,
            "stage_ms": {stage: seconds / max(frames, 1) * 1e3 for stage, seconds in stage_s.items()},
            "score": None if score is None else (score.tp, score.fp, score.fn),  # type: ignore[attr-defined]
            "registration": result.describe_registration(), "poses": [w.pose_source for w in result.worlds.values()],
            "stages": "at the same time" if overlap else "one after the other", "workers": workers or RunOptions().workers,
            "machine": machine()}


def _cpu_s() -> float:
    """CPU seconds of this process and of its children that have ended (the run's worker processes)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def raw_pass_of(tree: Path, ref: str, source: Path, target: Path, threads: int = 1, frame_step: int = 1) -> dict:
    """The raw pass as the code of git revision `ref` of this checkout runs it (its files in `tree`,
    from `ndfa.eval.revision.revision_tree`; run in a child process): that revision's own `raw_pass`
    where it has one (every stage, timed as now's), else `ndfa detect SOURCE TARGET --json`:
    `wall_s`, `fps`, `cpu_s` (the child's), `score`, and the stage timings its summary gives
    (`stage_ms_target`: ms per target frame of the target pass). The wall and CPU time of the
    latter include the child's start (Python, the NDF's loading: a few seconds), which `raw_pass`
    leaves out."""
    import json

    module = tree / "ndfa" / "eval" / "bench_raw.py"
    if module.is_file() and "def raw_pass(" in (text := module.read_text()) and "frame_step: int" in text:
        out = tree / "raw_pass.json"
        run_in_tree(tree, ref, ["-c", _RAW_PASS_IN_CHILD, str(source.resolve()), str(target.resolve()), str(threads),
                                str(frame_step), str(out)], "its raw pass")
        before: dict = json.loads(out.read_text())
        return before | {"score": None if before["score"] is None else tuple(before["score"]),
                         "stages": f"as its raw pass ran them ({before['stages']})"}
    summary = tree / "summary.json"
    wall_s, cpu_s = run_in_tree(tree, ref, ["-c", "from ndfa.cli import main; main()", "detect", str(source.resolve()),
                                            str(target.resolve()), "--threads", str(threads),
                                            "--frame-step", str(frame_step), "--json", str(summary)], "ndfa detect")
    result = json.loads(summary.read_text())
    frames = len(RecordingReader(source)) + len(RecordingReader(target))  # input frames, as `raw_pass` counts them
    return {"frames": frames, "frames_used": int(result["frames"]), "wall_s": wall_s, "fps": frames / wall_s, "cpu_s": cpu_s,
            "stage_ms": {}, "stage_ms_target": result.get("stage_ms", {}),
            "score": (result["tp"], result["fp"], result["fn"]) if "tp" in result else None,
            "stages": "as ndfa detect ran them at that revision", "machine": machine()}


# What the before's child runs where its revision has `raw_pass` (`raw_pass_of`): argv source,
# target, threads, frame step, the JSON to write.
_RAW_PASS_IN_CHILD = """
import json, sys
from pathlib import Path
from ndfa.eval.bench_raw import raw_pass
result = raw_pass(Path(sys.argv[1]), Path(sys.argv[2]), threads=int(sys.argv[3]), frame_step=int(sys.argv[4]))
Path(sys.argv[5]).write_text(json.dumps(result))
"""


def raw_pass_runs(source: Path, target: Path, now: PipelineConfig | None = None, before_ref: str | None = None,
                  load: bool = False, repeat: int = 1, threads: int = 1, frame_step: int = 1,
                  workers: int | None = None, rate_hz: float | None = DEFAULT_RATE_HZ,
                  before_frame_step: int | None = None) -> list[dict]:
    """`raw_pass` with the config `now` (default: the shipped one) `repeat` times, each row
    labelled; with `before_ref` (a git revision of this checkout), the raw pass as that revision
    ran it (`raw_pass_of`), alternating with now (`ndfa.eval.revision.alternate`). A label's row
    is its run of median frames/s, every run's in `fps_runs`. With `load`, now once more beside
    one busy process. `workers`: now's (default `RunOptions.workers`); the before runs as its revision did.
    `rate_hz` (`ndfa detect --rate`): now's only; `before_frame_step`: the before's (default `frame_step`).
    Every row also gives `recorded_s` (both sessions' recorded time) and `realtime` (that over its wall)."""
    now_run = functools.partial(raw_pass, source, target, now, threads, frame_step, workers=workers, rate_hz=rate_hz)
    with contextlib.ExitStack() as stack:
        before = None
        if before_ref is not None:
            tree = stack.enter_context(revision_tree(before_ref))
            before = functools.partial(raw_pass_of, tree, before_ref, source, target, threads,
                                       frame_step if before_frame_step is None else before_frame_step)
        rows = alternate(now_run, before, repeat)
    if load:
        rows.append({"label": "now, beside one busy process"} | beside_busy_process(now_run))
    recorded_s = recorded_seconds(RecordingReader(source).timestamps()) + recorded_seconds(RecordingReader(target).timestamps())
    return [row | {"recorded_s": recorded_s, "realtime": recorded_s / row["wall_s"]} for row in rows]
