"""`ndfa eval --sweep`: robustness sweeps of ndfa and the NN and PMT baselines.

A sweep varies one axis of the synthetic world (target pose drift, depth noise, mugs per table,
view overlap) over a list of values and several seeds. Each cell (axis, value, seed) is an
independent task: render the pair of recordings for the cell into a temporary directory, run
`ndfa.eval.table.evaluate_methods` on it, return one row per method, delete the recordings.

Cells run on Ray when it is installed and wanted (`pip install ndfa[cluster]`; `ray.init()` on
the local cores, or `address=` for a cluster; a cell lost with its worker or node is run again,
see `ndfa.eval.sweep_ray`), otherwise in a local process pool (or in this process with
`workers=1`). Results are keyed by the cell's parameters (`cell_id`) and appended to
`DIR/sweep.parquet` by this process as each cell finishes (written atomically, once per cell), so
an interrupted sweep resumes where it stopped and never recomputes a finished cell.
`ndfa.eval.plots` draws a sweep; docs/sweeps.md tells how to run one on a cluster.
"""

from __future__ import annotations

import dataclasses
import functools
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import polars as pl

from ndfa.core.errors import SweepError
from ndfa.eval.sweep_ray import run_cells_on_ray
from ndfa.io.atomic import write_parquet
from ndfa.sim.noise import DepthNoise
from ndfa.sim.presets import make_config

METHODS = ("NN", "PMT", "ndfa")
ROUTES_FOR_OVERLAP = ("perimeter", "corridor", "weave", "circles")
DRIFT_YAW_DEG_PER_M = 25.0  # yaw drift scaled along with translation drift (the `random` preset's ratio 0.05 / 0.002)

SCHEMA = {
    "cell_id": pl.Utf8, "preset": pl.Utf8, "axis": pl.Utf8, "value": pl.Utf8, "x": pl.Float64, "seed": pl.Int64,
    "step_m": pl.Float64, "method": pl.Utf8, "tp": pl.Int64, "fp": pl.Int64, "fn": pl.Int64,
    "precision": pl.Float64, "recall": pl.Float64, "f1": pl.Float64, "seconds": pl.Float64,
    "render_seconds": pl.Float64,
}


@dataclass(frozen=True)
class SweepSpec:
    """One axis, its values, the seeds and the base preset. `step_m` overrides the preset's camera
    travel between frames (a larger step: fewer frames, faster cells)."""

    axis: str
    values: tuple[str, ...]
    seeds: tuple[int, ...]
    preset: str = "sample"
    step_m: float | None = None

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise SweepError(f"unknown sweep axis {self.axis!r}; expected one of {', '.join(AXES)}")
        if not self.values:
            raise SweepError("a sweep needs at least one value")
        if not self.seeds:
            raise SweepError("a sweep needs at least one seed")
        object.__setattr__(self, "values", tuple(_normalise(self.axis, v) for v in self.values))
        object.__setattr__(self, "seeds", tuple(int(s) for s in self.seeds))

    def cells(self) -> list["Cell"]:
        return [Cell(self.preset, self.axis, value, seed, self.step_m) for value in self.values for seed in self.seeds]


@dataclass(frozen=True)
class Cell:
    preset: str
    axis: str
    value: str
    seed: int
    step_m: float | None = None

    @property
    def key(self) -> str:
        step = "preset" if self.step_m is None else f"{self.step_m:g}"
        return f"{self.preset}|{self.axis}={self.value}|seed={self.seed}|step={step}"

    @property
    def x(self) -> float:
        """The value as a number for tables and plots (overlap: the route's index)."""
        if self.axis == "overlap":
            return float(ROUTES_FOR_OVERLAP.index(self.value))
        return float(self.value)


def _drift(config, value: str) -> dict:
    d = float(value)
    return {"target_pose_error": dataclasses.replace(config.target_pose_error, drift_translation_m=d,
                                                     drift_yaw_deg=DRIFT_YAW_DEG_PER_M * d)}


def _noise(config, value: str) -> dict:
    k = float(value)
    return {"depth_noise": DepthNoise.off() if k == 0 else DepthNoise().scaled(k)}


def _objects(config, value: str) -> dict:
    n = int(value)
    return {"mugs_per_table": (n, n), "total_mugs": None}


def _overlap(config, value: str) -> dict:
    # View overlap between the sessions: the target follows the source's route (most overlap) or another
    # one (corridor: half the tables from the other side).
    return {"source_route": "perimeter", "target_route": value}


AXES: dict[str, Callable[[object, str], dict]] = {"drift": _drift, "noise": _noise, "objects": _objects,
                                                  "overlap": _overlap}
AXIS_HELP = {
    "drift": "target drift, metres/frame random-walk step (yaw drift 25 deg per metre along; the preset's offset stays on)",
    "noise": "depth-noise std as a multiple of the default sensor's (0 = noise off)",
    "objects": "mugs per table in the source",
    "overlap": f"target route ({', '.join(ROUTES_FOR_OVERLAP)}; the source follows perimeter)",
}


def _normalise(axis: str, value) -> str:
    text = str(value).strip()
    try:
        if axis == "overlap":
            if text not in ROUTES_FOR_OVERLAP:
                raise ValueError
            return text
        if axis == "objects":
            n = int(text)
            if n < 0:
                raise ValueError
            return str(n)
        v = float(text)
        if v < 0:
            raise ValueError
        return f"{v:g}"
    except ValueError:
        raise SweepError(f"bad value {text!r} for sweep axis {axis!r}: {AXIS_HELP[axis]}") from None


def parse_seeds(text: str) -> tuple[int, ...]:
    """'0-4' -> (0, 1, 2, 3, 4); '1,3,7' -> (1, 3, 7); mixes allowed ('0-2,9')."""
    seeds: list[int] = []
    try:
        for part in text.split(","):
            part = part.strip()
            if not part:
                continue
            lo, sep, hi = part.partition("-")
            seeds.extend(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    except ValueError:
        raise SweepError(f"--seeds must be N, LO-HI or a comma list of them, got {text!r}") from None
    if not seeds:
        raise SweepError(f"--seeds {text!r} names no seed")
    return tuple(dict.fromkeys(seeds))


def cell_config(cell: Cell):
    base = make_config(cell.preset, cell.seed)
    overrides = AXES[cell.axis](base, cell.value)
    if cell.step_m is not None:
        overrides["trajectory"] = dataclasses.replace(base.trajectory, step_m=cell.step_m)
    return make_config(cell.preset, cell.seed, **overrides)


def run_cell(cell: Cell, workdir: Path, threads: int | None = None) -> list[dict]:
    """Render the cell's scene into a temporary directory under `workdir` (on a cluster node that
    cannot make it: the node's temporary folder), evaluate the three methods on it and return one row
    per method. The recordings are deleted afterwards."""
    # torch and open3d (the methods, the renderer) load only where cells are computed, not in the driver or plots
    from ndfa.eval.table import evaluate_methods
    from ndfa.io.ingest.synthetic import ingest_sim

    if threads is not None:
        import torch

        torch.set_num_threads(max(1, threads))
    config = cell_config(cell)
    try:
        Path(workdir).mkdir(parents=True, exist_ok=True)
        scratch = Path(tempfile.mkdtemp(prefix="cell-", dir=workdir))
    except OSError:  # a cluster node that cannot make the driver's folder: its own temporary folder
        scratch = Path(tempfile.mkdtemp(prefix="ndfa-cell-"))
    try:
        started = time.perf_counter()
        ingest_sim(config, scratch / "pair")
        render_seconds = time.perf_counter() - started
        result = evaluate_methods(scratch / "pair" / "source.mcap", scratch / "pair" / "target.mcap")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    rows = []
    for r in result.rows:
        f1 = 2 * r.precision * r.recall / (r.precision + r.recall) if r.precision + r.recall > 0 else 0.0
        rows.append({"cell_id": cell.key, "preset": cell.preset, "axis": cell.axis, "value": cell.value, "x": cell.x,
                     "seed": cell.seed, "step_m": cell.step_m, "method": r.method, "tp": r.tp, "fp": r.fp, "fn": r.fn,
                     "precision": float(r.precision), "recall": float(r.recall), "f1": float(f1),
                     "seconds": float(r.seconds), "render_seconds": render_seconds})
    return rows


ComputeCell = Callable[[Cell, Path, "int | None"], list[dict]]  # run_cell's signature


def _run_cell_safely(cell: Cell, workdir: Path, threads: int | None,
                     compute: ComputeCell | None = None) -> tuple[Cell, list[dict] | None, str | None]:
    try:
        return cell, (compute or run_cell)(cell, workdir, threads), None
    except Exception as error:  # noqa: BLE001 -- reported per cell, the other cells go on
        return cell, None, f"{type(error).__name__}: {error}"


def load_results(path: Path) -> pl.DataFrame:
    """The results written so far (empty if none), or a SweepError for a file that is not one."""
    path = Path(path)
    if not path.exists():
        return pl.DataFrame(schema=SCHEMA)
    try:
        table = pl.read_parquet(path)
    except Exception as error:  # noqa: BLE001
        raise SweepError(f"{path} is not a readable sweep results file ({type(error).__name__}: {error}); "
                         "move it away or delete it to start the sweep over") from None
    missing = [c for c in SCHEMA if c not in table.columns]
    if missing:
        raise SweepError(f"{path} is not a sweep results file: it lacks the columns {', '.join(missing)}; "
                         "move it away or delete it to start the sweep over")
    return table.select(list(SCHEMA)).cast(SCHEMA)


@dataclass
class SweepRun:
    table: pl.DataFrame        # all rows of the spec's cells (finished earlier or now)
    computed: int              # cells computed in this run
    skipped: int               # cells found finished in the results file
    failed: dict[str, str]     # cell key -> error
    backend: str               # "ray", "processes" or "in-process"
    seconds: float
    lost: dict[str, str] = dataclasses.field(default_factory=dict)  # Ray: cells whose worker or node died, run again


def run_sweep(spec: SweepSpec, out: Path, workers: int | None = None, address: str | None = None,
              use_ray: bool | None = None, on_cell: Callable[[Cell, str | None, int, int], None] | None = None,
              compute: ComputeCell | None = None) -> SweepRun:
    """Run the spec's unfinished cells, appending each cell's rows to `out/sweep.parquet` as it finishes.

    use_ray: None = Ray when importable (always when `address` is given), True = require it, False = never.
    workers: parallel cells for the process pool (default: the CPU count; 1 = in this process).
    compute: what computes one cell (default `run_cell`); it must be picklable for Ray and the pool.
    """
    started = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "sweep.parquet"
    results = load_results(path)
    done = set(results["cell_id"].unique().to_list())
    cells = spec.cells()
    pending = [c for c in cells if c.key not in done]
    skipped = len(cells) - len(pending)
    workdir = out.resolve() / ".cells"  # absolute: Ray workers do not share this process's working directory
    cpus = os.cpu_count() or 1
    workers = max(1, min(workers or cpus, max(1, len(pending))))
    threads = max(1, cpus // workers)

    ray = None
    if use_ray is not False and pending:
        try:
            import ray  # type: ignore[import-not-found]
        except ImportError:
            if use_ray or address is not None:
                raise SweepError("Ray is not installed: pip install 'ndfa[cluster]' (or run without --address "
                                 "to use a local process pool)") from None
            ray = None
    backend = "ray" if ray is not None else ("processes" if workers > 1 else "in-process")

    failed: dict[str, str] = {}
    lost: dict[str, str] = {}
    finished = 0

    def collect(cell: Cell, rows: list[dict] | None, error: str | None) -> None:
        nonlocal results, finished
        if cell.key in done or cell.key in failed:
            return  # a cell reported twice (its first run was thought lost) enters the results once
        finished += 1
        if error is not None:
            failed[cell.key] = error
        else:
            results = pl.concat([results, pl.DataFrame(rows, schema=SCHEMA)])
            write_parquet(results, path)
            done.add(cell.key)
        if on_cell is not None:
            on_cell(cell, error, finished, len(pending))

    try:
        if not pending:
            pass
        elif ray is not None:
            run_one = functools.partial(_run_cell_safely, workdir=workdir, threads=1, compute=compute)
            lost = run_cells_on_ray(pending, run_one, collect, address)
        elif workers == 1:
            for c in pending:
                collect(*_run_cell_safely(c, workdir, None, compute))
        else:
            _run_in_pool(pending, workdir, workers, threads, compute, collect, path)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    keys = [c.key for c in cells]
    table = results.filter(pl.col("cell_id").is_in(keys)).sort(["x", "seed", "method"])
    return SweepRun(table, len(pending) - len(failed), skipped, failed, backend, time.perf_counter() - started, lost)


def _run_in_pool(cells: list[Cell], workdir: Path, workers: int, threads: int, compute: ComputeCell | None,
                 collect: Callable[[Cell, list[dict] | None, str | None], None], path: Path) -> None:
    """The cells in a local pool of spawned processes. A pool whose process dies (killed, out of memory)
    cannot go on: the cells finished so far are saved, and the error says to run again to resume."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(_run_cell_safely, c, workdir, threads, compute) for c in cells]
        try:
            for future in as_completed(futures):
                collect(*future.result())
        except BrokenProcessPool:
            raise SweepError(f"a sweep worker process died (killed or out of memory); the cells finished so far "
                             f"are saved in {path}: run the sweep again to compute the rest") from None


def aggregate(table: pl.DataFrame) -> pl.DataFrame:
    """Per (axis, value, method): seeds, summed TP/FP/FN, mean precision/recall/F1 with F1's min and max."""
    return (table.group_by(["axis", "value", "x", "method"])
            .agg(pl.col("seed").n_unique().alias("seeds"), pl.col("tp").sum(), pl.col("fp").sum(), pl.col("fn").sum(),
                 pl.col("precision").mean(), pl.col("recall").mean(), pl.col("f1").mean().alias("f1"),
                 pl.col("f1").min().alias("f1_min"), pl.col("f1").max().alias("f1_max"),
                 pl.col("seconds").mean().alias("seconds"))
            .sort(["axis", "x", "method"]))


def spec_from_text(axis: str, values: str, seeds: str, preset: str = "sample", step_m: float | None = None) -> SweepSpec:
    """The CLI's strings ('0,0.001,0.002', '0-4') as a SweepSpec."""
    items: Sequence[str] = [v for v in values.split(",") if v.strip()]
    return SweepSpec(axis, tuple(items), parse_seeds(seeds), preset, step_m)
