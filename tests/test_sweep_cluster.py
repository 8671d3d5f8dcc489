"""A sweep on a real two-node Ray cluster on this machine, its worker node killed in the middle.

The head and a worker node are started with `ray start` (one CPU each, their own temp folders and
ports), the sweep connects with `address=`, and once the worker node has finished a cell and
started the next, its raylet and everything under it get SIGKILL. The sweep must finish on the
head node with every cell in the results once, each cell computed once to the end (a log written
by the cells counts them), and a re-run must compute nothing.

The cluster is stopped by killing the processes it started, found by their temp folder, in a
finalizer (so also when the test fails); `ray stop --force` is not used because it kills every Ray
process of the user on the machine, a colleague's included.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import polars as pl
import pytest

from ndfa.eval.sweep import SweepSpec, load_results, run_sweep
from ndfa.eval.sweep_ray import LOST_CELL_RESUBMITS

pytest.importorskip("ray", reason="Ray is not installed: the cluster extra (pip install 'ndfa[cluster]')")
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds Ray's processes in /proc")]

REPO = Path(__file__).resolve().parents[1]
# Ray 2.60 turns token authentication on for a head node when ~/.ray/auth_token exists (any local
# ray.init() writes one) but not for a node joining it, which then cannot connect: every process
# of this cluster, the driver included, is told the same instead.
NO_TOKEN = {"RAY_AUTH_MODE": "disabled"}
RAY = Path(sys.executable).with_name("ray")
SPEC = SweepSpec("drift", ("0", "0.002", "0.004"), (0, 1), step_m=2.0)  # 6 cells of ~2 s: the sample scene, few frames


def _processes() -> dict[int, tuple[int, str]]:
    """pid -> (parent pid, command line) of every process we may see."""
    found = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            cmdline = Path(f"/proc/{entry}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            parent = int(Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        found[int(entry)] = (parent, cmdline)
    return found


def _with_descendants(roots: set[int], processes: dict[int, tuple[int, str]]) -> set[int]:
    tree = set(roots)
    grew = True
    while grew:
        children = {pid for pid, (parent, _) in processes.items() if parent in tree} - tree
        tree |= children
        grew = bool(children)
    return tree


def _kill_processes_of(folder: Path) -> set[int]:
    """SIGKILL every process whose command line names `folder` (Ray's node processes carry their
    session folder) and everything they started (workers, agents). Returns the pids killed."""
    processes = _processes()
    roots = {pid for pid, (_, cmdline) in processes.items() if str(folder) in cmdline and pid != os.getpid()}
    doomed = _with_descendants(roots, processes) - {os.getpid()}
    for pid in doomed:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return doomed


def _free_ports(count: int) -> list[int]:
    sockets = [socket.socket() for _ in range(count)]
    try:
        for s in sockets:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in sockets]
    finally:
        for s in sockets:
            s.close()


def _ray_start(folder: Path, *args: str) -> None:
    """`ray start` a node whose files lie in `folder`, with ports of its own and little memory."""
    agent, agent_grpc, runtime_env, metrics = _free_ports(4)
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1", RAY_USAGE_STATS_ENABLED="0", **NO_TOKEN)
    command = [str(RAY), "start", *args, "--num-cpus=1", "--object-store-memory=100000000",
               f"--temp-dir={folder}", "--disable-usage-stats", f"--dashboard-agent-listen-port={agent}",
               f"--dashboard-agent-grpc-port={agent_grpc}", f"--runtime-env-agent-port={runtime_env}",
               f"--metrics-export-port={metrics}"]
    result = subprocess.run(command, env=env, capture_output=True, text=True, timeout=90)
    assert result.returncode == 0, f"{' '.join(command)} failed:\n{result.stdout[-2000:]}\n{result.stderr[-2000:]}"


@dataclass
class Cluster:
    address: str
    head: Path    # the head node's temp folder
    worker: Path  # the worker node's

    def raylet(self, folder: Path) -> int:
        pids = [pid for pid, (_, cmdline) in _processes().items() if "raylet/raylet " in cmdline and str(folder) in cmdline]
        assert len(pids) == 1, pids
        return pids[0]


@pytest.fixture(scope="module")
def cluster() -> Iterator[Cluster]:
    """Head and worker node for this module's tests (the first kills the worker node)."""
    # A short folder under /tmp: Ray's unix socket paths inside it must stay under 108 characters.
    root = Path(tempfile.mkdtemp(prefix="ndfa-ray-", dir="/tmp"))
    head, worker = root / "head", root / "worker"
    with pytest.MonkeyPatch.context() as monkeypatch:
        for name, value in NO_TOKEN.items():
            monkeypatch.setenv(name, value)
        yield from _start_cluster(root, head, worker)


def _start_cluster(root: Path, head: Path, worker: Path) -> Iterator[Cluster]:
    try:
        port, dashboard = _free_ports(2)
        _ray_start(head, "--head", f"--port={port}", "--include-dashboard=false", f"--dashboard-port={dashboard}")
        _ray_start(worker, f"--address=127.0.0.1:{port}")
        yield Cluster(f"127.0.0.1:{port}", head, worker)
    finally:
        _kill_processes_of(root)
        shutil.rmtree(root, ignore_errors=True)


def _events(log: Path) -> list[tuple[str, str, int, int]]:
    """The cells' log: (start or done, cell key, pid, parent pid: the raylet of the node it ran on)."""
    if not log.exists():
        return []
    return [(e, k, int(p), int(pp)) for e, k, p, pp in (line.split("\t") for line in log.read_text().splitlines())]


@pytest.mark.timeout(240)
def test_sweep_survives_a_killed_worker_node(cluster: Cluster, tmp_path: Path):
    out = tmp_path / "sweep"
    out.mkdir()
    log = tmp_path / "computations.log"

    def counted_cell(cell, workdir, threads):
        """The real cell, logged when it starts and when it has computed its rows. A closure: Ray
        sends it to the workers by value (they cannot import this test module)."""
        import os

        from ndfa.eval.sweep import run_cell

        def log_event(event: str) -> None:
            # One short O_APPEND write per line: lines from cells on both nodes never interleave.
            fd = os.open(log, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
            try:
                os.write(fd, f"{event}\t{cell.key}\t{os.getpid()}\t{os.getppid()}\n".encode())
            finally:
                os.close(fd)

        log_event("start")
        rows = run_cell(cell, workdir, threads)
        log_event("done")
        return rows

    head_raylet, worker_raylet = cluster.raylet(cluster.head), cluster.raylet(cluster.worker)
    killed: dict[str, object] = {}

    def kill_worker_node_mid_cell() -> None:
        """Once the worker node has finished a cell and started another: SIGKILL its raylet, the
        workers under it and its log monitor."""
        deadline = time.monotonic() + 150
        while time.monotonic() < deadline and not killed:
            events = [(e, k, p) for e, k, p, raylet in _events(log) if raylet == worker_raylet]
            finished = {k for e, k, _ in events if e == "done"}
            running = [(k, p) for e, k, p in events if e == "start" and k not in finished]
            if finished and running:
                killed["pids"] = _kill_processes_of(cluster.worker)
                killed["cell"], killed["pid"] = running[0]
                killed["at"] = len(_events(log))
                return
            time.sleep(0.05)

    watcher = threading.Thread(target=kill_worker_node_mid_cell, daemon=True)
    watcher.start()
    started = time.monotonic()
    run = run_sweep(SPEC, out, address=cluster.address, compute=counted_cell)
    seconds = time.monotonic() - started
    watcher.join(timeout=5)

    assert killed, "the worker node never ran a second cell: nothing was killed"
    assert worker_raylet in killed["pids"] and killed["pid"] in killed["pids"]
    assert run.backend == "ray" and not run.failed, run.failed
    assert run.computed == 6 and run.skipped == 0
    assert killed["cell"] in run.lost, run.lost  # the killed cell was seen lost and run again

    # Every cell in the results once (three methods each), none lost.
    table = load_results(out / "sweep.parquet")
    assert sorted(table.group_by("cell_id").len()["len"].to_list()) == [3] * 6
    assert set(table["cell_id"]) == {c.key for c in SPEC.cells()}
    assert run.table.height == 18

    # Each cell computed to the end exactly once: the killed one not on the dead node, and every cell
    # after the kill on the head node.
    events = _events(log)
    done = [k for e, k, _, _ in events if e == "done"]
    assert sorted(done) == sorted(c.key for c in SPEC.cells()), events
    assert ("done", killed["cell"]) not in [(e, k) for e, k, p, _ in events if p == killed["pid"]]
    assert all(raylet == head_raylet for e, _, _, raylet in events[killed["at"]:]), events
    assert not (out / ".cells").exists()  # the killed cell's scratch files are gone too
    print(f"\nsweep with the worker node killed: {seconds:.1f} s; lost and run again: {run.lost}")

    # A re-run computes nothing.
    again = run_sweep(SPEC, out, address=cluster.address, compute=counted_cell)
    assert again.computed == 0 and again.skipped == 6 and not again.failed
    assert _events(log) == events
    assert again.table.sort(["cell_id", "method"]).equals(run.table.sort(["cell_id", "method"]))
    assert pl.read_parquet(out / "sweep.parquet").height == 18


@pytest.mark.timeout(120)
def test_a_cell_that_keeps_killing_its_worker_fails_alone(cluster: Cluster, tmp_path: Path):
    spec = SweepSpec("drift", ("0", "0.002", "0.004"), (0,))

    def deadly_cell(cell, workdir, threads):
        """0.002 kills the Ray worker running it (as a segfault in a native library would); the others
        return made-up rows at once."""
        import os
        import signal

        if cell.value == "0.002":
            os.kill(os.getpid(), signal.SIGKILL)
        return [{"cell_id": cell.key, "preset": cell.preset, "axis": cell.axis, "value": cell.value, "x": cell.x,
                 "seed": cell.seed, "step_m": cell.step_m, "method": "NN", "tp": 1, "fp": 0, "fn": 0,
                 "precision": 1.0, "recall": 1.0, "f1": 1.0, "seconds": 0.0, "render_seconds": 0.0}]

    run = run_sweep(spec, tmp_path, address=cluster.address, compute=deadly_cell)
    deadly = spec.cells()[1].key
    assert list(run.failed) == [deadly] and run.failed[deadly].startswith(f"lost {LOST_CELL_RESUBMITS + 1} times")
    assert "WorkerCrashedError" in run.failed[deadly] and list(run.lost) == [deadly]
    assert run.computed == 2 and sorted(run.table["value"]) == ["0", "0.004"]
    assert load_results(tmp_path / "sweep.parquet")["cell_id"].to_list() == [c.key for c in spec.cells()[::2]]
