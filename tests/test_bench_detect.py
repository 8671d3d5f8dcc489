"""`ndfa bench detect`: the before / now / under-load rows of one run (the speed figures live in
docs/speed.md; here only that every row is there and scores the same)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from ndfa.cli import app
from ndfa.core.errors import OptionError
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
