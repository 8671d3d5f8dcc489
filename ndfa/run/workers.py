"""What runs where in a pass over sessions (`ndfa.run.sessions.session_pass`): the one place that
decides it.

The pass itself (each session's frames read, perceived, encoded in threads and decided on here,
`ndfa.run.stream.staged`) runs in this process, session after session. What a session needs before
its pass is its world (poses by odometry where it has none, up: `ndfa.run.world.prepare_session`)
and, for the target of a pair, the pair's scene-level hypothesis of T_rel
(`ndfa.run.align.registration_prior`: the scene clouds aligned). With `workers` >= 2 and a session
after the first whose poses are estimated (the expensive case: a raw recording), these run ahead in
`workers - 1` other processes:

- every session's world after the first is started at once, while this process estimates the
  first's; then
- each pair's hypothesis is started as soon as both its sessions' worlds are known (`poll`, between
  the source's frames), while this process runs the source's pass; the target's pass waits for it.

Otherwise (`workers` 1, or every session's poses given) everything runs here, one after the other,
as before. The results are the same either way: the same functions on the same inputs. The worker
is started by "spawn" (a fresh interpreter: nothing of this process's threads or NDF runtime) and
inherits the environment (OMP_NUM_THREADS among it); Open3D's estimators run on one thread in it
as here (`ndfa.trajectory.open3d_threads`). What the caller sees in which order does not depend on
the timing either: a world is handed over (`world`) and a hypothesis (`alignment`) where the pass
needs it. The worker's wall seconds come back in `SessionWorld.seconds` and
`SceneAlignment.seconds`; its CPU time is the process's children's once `close` has waited for it.

`--threads` stays the threads of the NDF's runtime in this process (`ndfa detect --threads`);
`--workers` (`RunOptions.workers`) is the processes: `--workers 1 --threads 1` keeps the run to this
process (its stages still overlap in threads, docs/speed.md).
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from pathlib import Path

from ndfa.io.recording import RecordingReader
from ndfa.run.align import RegistrationMode, SceneAlignment, registration_prior, scene_depth
from ndfa.run.cloud_align import AlignConfig
from ndfa.run.world import KeepDepth, PoseMode, SessionWorld, UpMode, prepare_session

# Processes a run may use by default: this one and one worker (the project's machine has 2 cores).
WORKERS = 2


def needs_worker(readers: Sequence[RecordingReader], poses: PoseMode) -> bool:
    """Whether a session after the first has its poses estimated: what is worth another process."""
    return any(poses == "estimate" or (poses == "auto" and not reader.has_poses) for reader in readers[1:])


class Ahead:
    """The sessions' worlds and the pairs' hypotheses, run here or ahead in a worker (see the module docstring)."""

    def __init__(self, readers: Sequence[RecordingReader], names: Sequence[str], workers: int, up: UpMode,
                 poses: PoseMode, check_poses_backward: bool, registration: RegistrationMode, align: AlignConfig,
                 positions: Sequence[Sequence[int]] | None = None):
        self.readers, self.names = list(readers), list(names)
        # per session, the frames the run uses (`ndfa.run.rate`; None: every frame)
        self.positions: list[Sequence[int] | None] = list(positions) if positions is not None else \
            [None] * len(self.readers)
        self.world_args = (up, poses, check_poses_backward, scene_depth(align))
        self.registration, self.align = registration, align
        self.pool: ProcessPoolExecutor | None = None
        self.worlds: dict[int, SessionWorld] = {}
        self.future_worlds: dict[int, Future[SessionWorld]] = {}
        self.future_alignments: dict[int, Future[SceneAlignment | None]] = {}
        if workers >= 2 and needs_worker(self.readers, poses):
            self.pool = ProcessPoolExecutor(max_workers=min(workers - 1, len(self.readers) - 1),
                                            mp_context=multiprocessing.get_context("spawn"))
            for index in range(1, len(self.readers)):
                self.future_worlds[index] = self.pool.submit(_prepare, self.readers[index].path, self.names[index],
                                                             *self.world_args, self.positions[index])

    def before_passes(self) -> range:
        """The sessions whose worlds the caller takes before the first pass: every one when they
        are made here (as before: a session that cannot be tracked stops the run before any pass),
        the first when a worker makes the others."""
        return range(len(self.readers) if self.pool is None else 1)

    def world(self, index: int) -> SessionWorld:
        """Session `index`'s world (waiting for the worker's, where it runs there)."""
        if index not in self.worlds:
            future = self.future_worlds.get(index)
            self.worlds[index] = future.result() if future is not None else \
                prepare_session(self.readers[index], self.names[index], *self.world_args, self.positions[index])
        return self.worlds[index]

    def poll(self, pair: int) -> None:
        """Start pair `pair`'s hypothesis in the worker if both its worlds are known and it has not
        started (called between the source's frames: cheap). A session whose world failed in the
        worker (it cannot be tracked, no up) stops the run here, with its error, instead of after
        the passes before it."""
        if self.pool is None:
            return
        for future in self.future_worlds.values():
            if future.done() and future.exception() is not None:
                future.result()
        if pair in self.future_alignments or pair + 1 >= len(self.readers):
            return
        future = self.future_worlds.get(pair + 1)
        if pair in self.worlds and (future is None or future.done()):
            worlds = {"source": self.worlds[pair], "target": self.world(pair + 1)}
            self.future_alignments[pair] = self.pool.submit(
                _align, self.readers[pair].path, self.readers[pair + 1].path, worlds, self.registration, self.align)

    def alignment(self, pair: int) -> SceneAlignment | None:
        """Pair `pair`'s hypothesis (`registration_prior`), once both its worlds are known."""
        for index in (pair, pair + 1):
            self.world(index)
        if self.pool is None:
            return registration_prior(self.readers[pair], self.readers[pair + 1],
                                      {"source": self.worlds[pair], "target": self.worlds[pair + 1]},
                                      self.registration, self.align)
        self.poll(pair)
        return self.future_alignments[pair].result()

    def close(self) -> None:
        """Wait for the worker to end (what it still runs is cancelled where it has not started)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)


def _prepare(path: Path, name: str, up: UpMode, poses: PoseMode, check_poses_backward: bool,
             keep: KeepDepth, positions: Sequence[int] | None) -> SessionWorld:
    """`prepare_session` in the worker."""
    return prepare_session(RecordingReader(path), name, up, poses, check_poses_backward, keep, positions)


def _align(source: Path, target: Path, worlds: dict[str, SessionWorld], mode: RegistrationMode,
           config: AlignConfig) -> SceneAlignment | None:
    """`registration_prior` in the worker."""
    return registration_prior(RecordingReader(source), RecordingReader(target), worlds, mode, config)
