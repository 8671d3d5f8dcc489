"""`ndfa eval --sweep`: cells, resume, the results file and the plot (a tiny sample scene, in process)."""

import os
import signal
import socket
from pathlib import Path

import polars as pl
import pytest
from PIL import Image
from typer.testing import CliRunner

import ndfa.eval.sweep as sweep
from ndfa.cli import app
from ndfa.core.errors import SweepError
from ndfa.eval.plots import plot_sweep
from ndfa.eval.sweep import SweepSpec, cell_config, load_results, parse_seeds, run_sweep

TINY = dict(preset="sample", step_m=0.6)  # the sample scene with half its frames


def test_spec_cells_and_keys():
    spec = SweepSpec("drift", ("0", "0.0010", "2e-3"), parse_seeds("0-1,5"), **TINY)
    assert spec.values == ("0", "0.001", "0.002")
    assert spec.seeds == (0, 1, 5)
    cells = spec.cells()
    assert len(cells) == 9 and len({c.key for c in cells}) == 9
    config = cell_config(cells[-1])
    assert config.target_pose_error.drift_translation_m == 0.002
    assert config.target_pose_error.drift_yaw_deg > 0 and config.target_pose_error.offset_translation_m > 0
    assert config.trajectory.step_m == 0.6
    assert cell_config(SweepSpec("objects", ("2",), (0,)).cells()[0]).mugs_per_table == (2, 2)
    assert cell_config(SweepSpec("overlap", ("perimeter",), (0,)).cells()[0]).target_route == "perimeter"
    assert cell_config(SweepSpec("noise", ("0",), (0,)).cells()[0]).depth_noise.enabled is False


@pytest.mark.parametrize("axis, values", [("drift", ("-1",)), ("objects", ("x",)), ("overlap", ("sideways",)),
                                          ("tilt", ("1",))])
def test_bad_specs(axis, values):
    with pytest.raises(SweepError):
        SweepSpec(axis, values, (0,))


def test_bad_seeds():
    with pytest.raises(SweepError):
        parse_seeds("a-b")


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_sweep_runs_resumes_and_plots(tmp_path: Path, monkeypatch):
    spec = SweepSpec("drift", ("0", "0.004"), (0,), **TINY)
    run = run_sweep(spec, tmp_path, workers=1, use_ray=False)
    assert run.computed == 2 and run.skipped == 0 and not run.failed, run.failed
    table = pl.read_parquet(tmp_path / "sweep.parquet")
    assert table.height == 6
    assert sorted(table.group_by("cell_id").len()["len"].to_list()) == [3, 3]
    assert set(table["method"]) == {"NN", "PMT", "ndfa"}
    assert table["f1"].is_between(0, 1).all() and (table["tp"] + table["fn"] > 0).all()
    assert not (tmp_path / ".cells").exists()  # the rendered recordings are gone

    # A rerun computes nothing: every cell is already in the results file.
    def fail(*args, **kwargs):
        raise AssertionError("a finished cell was recomputed")

    monkeypatch.setattr(sweep, "run_cell", fail)
    again = run_sweep(spec, tmp_path, workers=1, use_ray=False)
    assert again.computed == 0 and again.skipped == 2
    assert again.table.sort(["cell_id", "method"]).equals(run.table.sort(["cell_id", "method"]))

    png = plot_sweep(again.table, tmp_path / "sweep_drift.png")
    assert Image.open(png).size[0] > 500

    # The CLI on the finished sweep: prints the table, writes the PNG, computes nothing.
    result = CliRunner().invoke(app, ["eval", "--sweep", "drift", "--values", "0,0.004", "--seeds", "0",
                                      "--step", "0.6", "--workers", "1", "--no-ray", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "0 cells computed, 2 already done" in result.output
    assert (tmp_path / "sweep_drift.png").exists()


def test_corrupt_results_file(tmp_path: Path):
    (tmp_path / "sweep.parquet").write_bytes(b"not a parquet file")
    with pytest.raises(SweepError, match="not a readable sweep results file"):
        load_results(tmp_path / "sweep.parquet")
    with pytest.raises(SweepError, match="not a readable sweep results file"):
        run_sweep(SweepSpec("drift", ("0",), (0,)), tmp_path, workers=1, use_ray=False)
    pl.DataFrame({"a": [1]}).write_parquet(tmp_path / "sweep.parquet")
    with pytest.raises(SweepError, match="lacks the columns"):
        load_results(tmp_path / "sweep.parquet")
    result = CliRunner().invoke(app, ["eval", "--sweep", "drift", "--values", "0", "--seeds", "0", "--no-ray",
                                      "--out", str(tmp_path)])
    assert result.exit_code != 0
    assert isinstance(result.exception, SweepError) and "lacks the columns" in str(result.exception)


def test_ray_required_but_missing(tmp_path: Path):
    try:
        import ray  # noqa: F401
    except ImportError:
        with pytest.raises(SweepError, match="Ray is not installed"):
            run_sweep(SweepSpec("drift", ("0",), (0,)), tmp_path, address="ray://nowhere:10001")
    else:
        pytest.skip("Ray is installed")


def test_no_cluster_at_the_address(tmp_path: Path):
    """An address where nothing listens: one line at once (ray.init alone would retry for minutes)."""
    pytest.importorskip("ray")
    with socket.socket() as s:  # a port that was free a moment ago
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SweepError, match=f"no Ray cluster answers at 127.0.0.1:{port}"):
        run_sweep(SweepSpec("drift", ("0",), (0,)), tmp_path, address=f"127.0.0.1:{port}")


def made_up_rows(cell) -> list[dict]:
    return [{"cell_id": cell.key, "preset": cell.preset, "axis": cell.axis, "value": cell.value, "x": cell.x,
             "seed": cell.seed, "step_m": cell.step_m, "method": "NN", "tp": 1, "fp": 0, "fn": 0, "precision": 1.0,
             "recall": 1.0, "f1": 1.0, "seconds": 0.0, "render_seconds": 0.0}]


def kills_its_process_on_0_004(cell, workdir, threads) -> list[dict]:
    """A cell whose process dies (as under the OOM killer) for one value; made-up rows for the others."""
    if cell.value == "0.004":
        os.kill(os.getpid(), signal.SIGKILL)
    return made_up_rows(cell)


@pytest.mark.timeout(120)
def test_a_dead_pool_process_is_one_line_and_the_rerun_resumes(tmp_path: Path):
    spec = SweepSpec("drift", ("0", "0.004"), (0,))
    with pytest.raises(SweepError, match="a sweep worker process died .* run the sweep again"):
        run_sweep(spec, tmp_path, workers=2, use_ray=False, compute=kills_its_process_on_0_004)
    saved = load_results(tmp_path / "sweep.parquet")["cell_id"].to_list()
    assert set(saved) <= {spec.cells()[0].key}  # only whole cells, and not the one that died
    assert not (tmp_path / ".cells").exists()
    again = run_sweep(spec, tmp_path, workers=1, use_ray=False, compute=lambda cell, workdir, threads: made_up_rows(cell))
    assert again.computed == 2 - len(saved) and again.skipped == len(saved)
    assert again.table["cell_id"].to_list() == [c.key for c in spec.cells()]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_ray_backend(tmp_path: Path):
    pytest.importorskip("ray")
    run = run_sweep(SweepSpec("drift", ("0",), (0,), **TINY), tmp_path, use_ray=True)
    assert run.backend == "ray" and run.computed == 1 and not run.failed, run.failed
    assert load_results(tmp_path / "sweep.parquet").height == 3


def test_eval_needs_recordings_or_sweep(tmp_path: Path):
    result = CliRunner().invoke(app, ["eval", "--out", str(tmp_path)])
    assert result.exit_code != 0
