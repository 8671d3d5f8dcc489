"""`ndfa bench raw`: the whole raw pass, per stage, before / now / beside a busy process in one run
(the speed figures live in docs/speed.md; here only that every stage is timed, and sanely)."""

from __future__ import annotations

import re

import pytest
from conftest import one_line
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.eval.bench_raw import RAW_STAGES
from ndfa.io.recording import RecordingReader


@pytest.mark.slow
def test_bench_raw_times_every_stage_of_both_sessions_before_now_and_under_load(small_raw_pair):
    # Now on every 2nd frame, the before on every frame: frames/s counts every input frame either way.
    result = CliRunner(env={"COLUMNS": "200"}).invoke(app, [
        "bench", "raw", "--source", str(small_raw_pair / "source.mcap"),
        "--target", str(small_raw_pair / "target.mcap"), "--compare", "--before-ref", "HEAD", "--load",
        "--frame-step", "2", "--before-frame-step", "1"])
    assert result.exit_code == 0, result.output
    columns = 3  # before, now, now beside one busy process
    rows = {}
    for line in result.output.splitlines():
        cells = [cell.strip() for cell in re.split(r"[│┃]", line)[1:-1]]
        if len(cells) == columns + 1:
            rows[cells[0]] = cells[1:]
    assert rows["ms / input frame (both sessions)"] == ["before", "now", "now, beside one busy process"]
    # The before is that revision's own raw pass (it has one), in a child process: its stages too.
    for stage in RAW_STAGES:
        assert all(float(ms) >= 0.0 for ms in rows[stage]), (stage, rows[stage])
    # Both sessions' poses were estimated and their up read from the planes: those stages took time,
    # as did every frame's segmentation.
    for stage in ("odometry", "up", "segmentation", "reading", "scene alignment"):
        assert all(float(ms) > 0.0 for ms in rows[stage]), (stage, rows[stage])
    assert "its own raw pass in a child process" in result.output
    frames = int(re.search(r"(\d+) input frames \(both sessions\)", result.output).group(1))
    assert frames > 50
    lengths = [len(RecordingReader(small_raw_pair / name)) for name in ("source.mcap", "target.mcap")]
    half = sum(len(range(0, n, 2)) for n in lengths)
    assert frames == sum(lengths) and rows["frames used (the rest skipped)"] == [str(frames), str(half), str(half)]
    for wall, fps in zip(rows["wall s"], rows["frames/s (input frames / wall)"]):
        assert float(fps) == pytest.approx(frames / float(wall), rel=0.05, abs=0.05)
    # How many times faster than the camera recorded both sessions: their recorded time over the wall.
    (label,) = [name for name in rows if name.startswith("x real time")]
    recorded = float(re.search(r"recorded ([\d.]+) s", label).group(1))
    times = [RecordingReader(small_raw_pair / name).timestamps() for name in ("source.mcap", "target.mcap")]
    period = times[0][1] - times[0][0]
    assert recorded == pytest.approx(sum(t[-1] - t[0] + period for t in times), abs=0.06)
    for wall, realtime in zip(rows["wall s"], rows[label]):
        assert float(realtime) == pytest.approx(recorded / float(wall), rel=0.05, abs=0.01)
    # Stages that run one after the other, before the frames' passes, fit in the wall time of the two
    # processes they run in (`--workers` 2, the default: the target's poses and the scene alignment
    # in the worker, `ndfa.run.workers`).
    for column, wall in enumerate(rows["wall s"][1:], start=1):
        before_pass = sum(float(rows[stage][column]) for stage in ("odometry", "up", "scene alignment"))
        assert before_pass * frames / 1e3 <= 2 * float(wall) * 1.01
    assert "2 process(es)" in result.output
    # The before's reports were scored as now's (Open3D's threaded RANSAC may differ run to run).
    assert all(re.fullmatch(r"\d+/\d+/\d+", cell) for cell in rows["TP / FP / FN"])
    assert "now over before:" in result.output and "beside one busy process:" in result.output


def test_bench_raw_refuses_an_unknown_revision(ndfa, small_raw_pair):
    one_line(ndfa("bench", "raw", "--source", small_raw_pair / "source.mcap", "--target", small_raw_pair / "target.mcap",
                  "--compare", "--before-ref", "no-such-revision"), "--before-ref no-such-revision")


def test_bench_raw_refuses_a_missing_recording(ndfa, tmp_path):
    one_line(ndfa("bench", "raw", "--source", tmp_path / "none.mcap", "--target", tmp_path / "none.mcap"), "none.mcap")


def _burn() -> None:
    sum(i * i for i in range(3_000_000))


def test_bench_raw_counts_the_cpu_of_the_worker_processes_it_waited_for():
    import multiprocessing

    from ndfa.eval.bench_raw import _cpu_s

    started = _cpu_s()
    child = multiprocessing.get_context("spawn").Process(target=_burn)
    child.start()
    child.join()
    assert child.exitcode == 0
    assert _cpu_s() - started > 0.1  # the child's work (here: its own import and the loop) counts
