"""The benchmarks' "before" and "now", back to back: `ndfa bench raw --compare` and `ndfa bench
detect --compare`.

A "before" can be an older git revision of this checkout (`--before-ref`): `revision_tree`
exports it once to a temporary directory and `run_in_tree` runs Python there in a child process,
whose `ndfa` is that tree's (the child's working directory is the tree: Python puts it ahead of
PYTHONPATH, so run from a checkout the child would otherwise import the checkout's `ndfa`).
`alternate` runs before and now in turns (before, now, before, now, ...), so that on a shared
machine both see the same load and their ratio holds where the absolute figures do not;
`beside_busy_process` runs a pass once more beside one busy process.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from ndfa.core.errors import NdfaError

CHECKOUT = Path(__file__).resolve().parents[2]
RAW_BEFORE_REF = "9004931"  # `ndfa bench raw --compare`'s before: main on the morning of 2026-12-03


@contextmanager
def revision_tree(ref: str) -> Iterator[Path]:
    """The files of git revision `ref` of this checkout in a temporary directory (removed after);
    an `NdfaError` naming `--before-ref REF` where it is not a revision."""
    with tempfile.TemporaryDirectory(prefix="ndfa-before-") as tmp:
        archive = subprocess.run(["git", "-C", str(CHECKOUT), "archive", "--format=tar", ref], capture_output=True)
        if archive.returncode != 0:
            reason = archive.stderr.decode().strip().splitlines()[:1]
            raise NdfaError(f"--before-ref {ref}: not a revision of {CHECKOUT} ({' '.join(reason)})")
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        yield Path(tmp)


def run_in_tree(tree: Path, ref: str, args: list[str], what: str) -> tuple[float, float]:
    """`python ARGS` in a child process in `tree` (from `revision_tree(ref)`), its `ndfa` the
    tree's: (wall seconds, the child's CPU seconds), both with the child's start. Paths in `args`
    must be absolute. An `NdfaError` naming `--before-ref REF` and `what` where the child fails."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    done = subprocess.run([sys.executable, *args], cwd=tree, env=os.environ | {"PYTHONPATH": str(tree)},
                          capture_output=True, text=True)
    wall_s = time.perf_counter() - started
    used = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        last = done.stderr.strip().splitlines()[-1:]
        raise NdfaError(f"--before-ref {ref}: {what} failed: {' '.join(last) or f'exit code {done.returncode}'}")
    return wall_s, used.ru_utime + used.ru_stime - children.ru_utime - children.ru_stime


def alternate(now: Callable[[], dict], before: Callable[[], dict] | None = None, repeat: int = 1) -> list[dict]:
    """`before` (if any) and `now` in turns, `repeat` times each: a row per label ("before",
    "now"), the label's run of median frames/s (`fps`) with every run's in `fps_runs`."""
    runs: dict[str, list[dict]] = {"before": [], "now": []}
    for _ in range(repeat):
        if before is not None:
            runs["before"].append(before())
        runs["now"].append(now())
    return [{"label": label} | _median_run(label_runs) for label, label_runs in runs.items() if label_runs]


def beside_busy_process(run: Callable[[], dict]) -> dict:
    """`run()` beside one busy process (`python -c 'while True: pass'`, started here and stopped
    after): whether a pass keeps its speed when the machine is shared."""
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        return run()
    finally:
        busy.kill()
        busy.wait()


def _median_run(runs: list[dict]) -> dict:
    median = sorted(runs, key=lambda run: run["fps"])[(len(runs) - 1) // 2]
    return median | {"fps_runs": [run["fps"] for run in runs]}
