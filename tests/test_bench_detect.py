"""`ndfa bench detect`: the before / now / under-load rows of one run (the speed figures live in
docs/speed.md; here only that every row is there and scores the same)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from conftest import one_line
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import NdfaError, OptionError
from ndfa.eval.bench import bench_detect_of
from ndfa.ndf.encoder import DEFAULT_WEIGHTS

SAMPLE = Path(__file__).parents[1] / "recordings" / "sample"


@pytest.mark.slow
def test_bench_detect_compares_before_and_now_and_under_load():
    result = CliRunner(env={"COLUMNS": "220"}).invoke(app, [
        "bench", "detect", "--source", str(SAMPLE / "source.mcap"), "--target", str(SAMPLE / "target.mcap"),
        "--frame-step", "30", "--compare", "--load", "--before-weights", str(DEFAULT_WEIGHTS),
        "--before-runtime", "torch", "--runtime", "onnxruntime", "--repeat", "3"])
    assert result.exit_code == 0, result.output
    assert "now, 3 runs: frames/s median" in result.output
    assert "before (torch, ndf_mugs.pt)" in result.output and "now (onnxruntime, shipped)" in result.output
    assert "speed-up of the target pass over the before" in result.output
    assert "beside one busy process:" in result.output


def test_bench_detect_refuses_an_unknown_runtime():
    result = CliRunner().invoke(app, ["bench", "detect", "--runtime", "gpu"])
    assert result.exit_code == 2 and "--runtime" in result.output


def test_bench_detect_with_fewer_points_and_neighbours():
    result = CliRunner(env={"COLUMNS": "220"}).invoke(app, [
        "bench", "detect", "--source", str(SAMPLE / "source.mcap"), "--target", str(SAMPLE / "target.mcap"),
        "--frame-step", "30", "--points", "224", "--neighbours", "10"])
    assert result.exit_code == 0, result.output
    assert "points / neighbours" in result.output and "224 / 10" in result.output


def test_bench_detect_refuses_too_few_points():
    result = CliRunner().invoke(app, ["bench", "detect", "--points", "5"])
    assert isinstance(result.exception, OptionError) and "--points must be >= 10" in str(result.exception)


def test_bench_detect_compares_with_a_git_revision_in_turns():
    result = CliRunner(env={"COLUMNS": "220"}).invoke(app, [
        "bench", "detect", "--source", str(SAMPLE / "source.mcap"), "--target", str(SAMPLE / "target.mcap"),
        "--frame-step", "30", "--compare", "--before-ref", "HEAD"])
    assert result.exit_code == 0, result.output
    assert "before at HEAD (onnxruntime, shipped)" in result.output and "now (onnxruntime, shipped)" in result.output
    scores = [line for line in result.output.splitlines() if "TP / FP / FN" in line]
    assert len(scores) == 1 and len(re.findall(r"\d+/\d+/\d+", scores[0])) == 2, scores
    assert "speed-up of the target pass over the before" in result.output


def _tree(tmp_path: Path, body: str) -> Path:
    """A stand-in revision: an `ndfa` package whose `ndfa.eval.bench.bench_detect` is `body`."""
    tree = tmp_path / "tree"
    (tree / "ndfa" / "eval").mkdir(parents=True)
    (tree / "ndfa" / "__init__.py").write_text("")
    (tree / "ndfa" / "eval" / "__init__.py").write_text("")
    (tree / "ndfa" / "eval" / "bench.py").write_text(
        "def bench_detect(source, target, threads, frame_step, runtime, weights, overlap):\n" + body)
    return tree


def test_the_before_is_the_revisions_code_even_when_run_from_the_checkout(tmp_path, monkeypatch):
    # Python puts the working directory ahead of PYTHONPATH: run from the checkout, a child that
    # did not start in the tree would time the checkout's own `ndfa`.
    tree = _tree(tmp_path, "    return {'fps': 7.0, 'score': [1, 2, 3], 'runtime': runtime,\n"
                           "            'args': [str(source), threads, frame_step, weights, overlap]}\n")
    monkeypatch.chdir(Path(__file__).parents[1])
    row = bench_detect_of(tree, "stand-in", Path("recordings/sample/source.mcap"), Path("t.mcap"), threads=1,
                          frame_step=5, runtime="torch", overlap=False)
    assert row["fps"] == 7.0 and row["score"] == (1, 2, 3) and row["ref"] == "stand-in" and row["runtime"] == "torch"
    assert row["args"] == [str((SAMPLE / "source.mcap").resolve()), 1, 5, None, False]


def test_a_failing_before_names_the_revision_and_the_child_s_last_line(tmp_path):
    tree = _tree(tmp_path, "    raise RuntimeError('no such stage')\n")
    with pytest.raises(NdfaError, match=r"--before-ref stand-in: bench_detect failed: RuntimeError: no such stage"):
        bench_detect_of(tree, "stand-in", SAMPLE / "source.mcap", SAMPLE / "target.mcap")


def test_bench_detect_refuses_an_unknown_revision(ndfa):
    one_line(ndfa("bench", "detect", "--source", SAMPLE / "source.mcap", "--target", SAMPLE / "target.mcap",
                  "--compare", "--before-ref", "no-such-revision"), "--before-ref no-such-revision")


def test_bench_refuses_a_before_ref_without_compare(ndfa):
    one_line(ndfa("bench", "detect", "--source", SAMPLE / "source.mcap", "--target", SAMPLE / "target.mcap",
                  "--before-ref", "HEAD"), "--before-ref", "--compare")
