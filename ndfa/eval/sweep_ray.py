"""A sweep's cells on Ray, so that a lost worker or node costs only the cells it was running.

Each cell is one Ray task with one CPU. Ray's own task retries are off (`max_retries=0`): when the
worker process running a cell dies, or its whole node does, `ray.get` raises a `RayError` here and
the driver submits the cell again (at most `LOST_CELL_RESUBMITS` times), to whichever node has a
free CPU. Doing it here rather than in Ray lets the sweep say which cells were lost and why
(`SweepRun.lost`), and a cell that keeps dying is reported as failed while the other cells go on.

Workers write nothing to the results: a task returns its cell's rows to the driver, which appends
them to the results file atomically (`ndfa.io.atomic`) and only once per cell. A worker killed in
the middle of a cell therefore leaves no half-written cell, and a resubmitted cell enters the
results once. What a killed cell had rendered lies in the sweep's scratch folder, which the driver
removes at the end.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

from ndfa.core.errors import SweepError

LOST_CELL_RESUBMITS = 3  # a cell whose worker or node died is run again this many times before it counts as failed


class KeyedCell(Protocol):
    """What this module needs of a cell (`ndfa.eval.sweep.Cell`): a key naming it in the results."""

    @property
    def key(self) -> str: ...


C = TypeVar("C", bound=KeyedCell)
CellResult = tuple[C, list[dict[str, Any]] | None, str | None]  # the cell, its rows or None, its error or None


def _run(run_one: Callable[[C], CellResult[C]], cell: C) -> CellResult[C]:
    """The Ray task: a module-level function, so that workers import it instead of unpickling code."""
    return run_one(cell)


def _one_line(error: BaseException, limit: int = 200) -> str:
    """Ray's messages run to several sentences of advice; the first names what happened."""
    lines = str(error).strip().splitlines()
    first = lines[0].split(". ")[0].rstrip(".") if lines else ""
    text = f"{type(error).__name__}: {first}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _answers(address: str, timeout_s: float = 5.0) -> bool:
    """Whether something accepts a connection at HOST:PORT (after an optional `ray://`): ray.init
    would otherwise retry an address where nothing listens for minutes. Other forms ('auto') pass."""
    import socket

    host, sep, port = address.split("://")[-1].rpartition(":")
    if not sep or not port.isdigit():
        return True
    try:
        socket.create_connection((host or "127.0.0.1", int(port)), timeout=timeout_s).close()
    except OSError:
        return False
    return True


def connect(address: str | None) -> bool:
    """`ray.init` on `address` (None: a Ray of this machine's cores) unless this process is already
    connected. Returns whether it connected, i.e. whether the caller should `ray.shutdown()`."""
    import ray

    if ray.is_initialized():
        return False
    if address is not None and not _answers(address):
        raise SweepError(f"no Ray cluster answers at {address} (start one with `ray start --head`, "
                         "or leave out the address to use this machine's cores)")
    try:
        ray.init(address=address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as error:
        where = f"the Ray cluster at {address}" if address else "a local Ray"
        raise SweepError(f"cannot start the sweep on {where}: {_one_line(error)}") from None
    return True


def run_cells_on_ray(cells: Sequence[C], run_one: Callable[[C], CellResult[C]],
                     collect: Callable[[C, list[dict[str, Any]] | None, str | None], None],
                     address: str | None = None, resubmits: int = LOST_CELL_RESUBMITS) -> dict[str, str]:
    """Run `run_one(cell)` for every cell on Ray and hand each result to `collect` as it arrives.

    `run_one` must be picklable and catch the cell's own errors (they are results, not losses).
    Returns the cells lost at least once on the way: cell key -> the last loss.
    """
    import ray
    from ray.exceptions import RayError

    connected = connect(address)
    try:
        task: Any = ray.remote(num_cpus=1, max_retries=0)(_run)
        running = {task.remote(run_one, cell): (cell, 0) for cell in cells}
        lost: dict[str, str] = {}
        while running:
            ready, _ = ray.wait(list(running), num_returns=1)
            cell, resubmitted = running.pop(ready[0])
            try:
                result = ray.get(ready[0])
            except RayError as error:  # the worker or node died (or the task could not run at all)
                lost[cell.key] = _one_line(error)
                if resubmitted < resubmits:
                    running[task.remote(run_one, cell)] = (cell, resubmitted + 1)
                    continue
                result = (cell, None, f"lost {resubmitted + 1} times; last: {lost[cell.key]}")
            collect(*result)
        return lost
    finally:
        if connected:
            ray.shutdown()
