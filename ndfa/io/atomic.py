"""Writing a file or folder so that no reader ever sees half of it: write beside it, then rename over it.

Everything ndfa writes goes through `Staged`: the temporary lies in a hidden folder next to the
destination (`.NAME.tmp-XXXXXXXX/NAME`), so that
- the final rename stays on one filesystem (os.replace is atomic only there);
- the temporary keeps the destination's own name: writers that derive something from it (numpy
  appending ".npz", PIL choosing the format by suffix, a ROS2 bag naming its database after its
  folder) write what they would write at the destination;
- a crash leaves at most one hidden folder, never half a file at the destination nor a clobbered
  previous one.

The rename replaces a file with a file and an empty folder with a folder, nothing else: a device
node, FIFO or socket at the destination (`/dev/null`, a named pipe) is refused before anything is
written and again at the rename, and so is a file where a folder goes or the other way round. These
and the filesystem's own refusals become `OutputError`, one line naming the destination.

A command's outputs together (`all_or_nothing`): inside it, every commit keeps what it replaced
(a hard link, in the hidden folder) until the block ends. A block that ends with an error undoes
every commit in reverse order (each replaced output back byte for byte, each new one removed),
drops every temporary not yet committed and removes the folders made for the declared outputs
(`declare_output`) that are left empty; one that ends without an error drops what was kept. Later
steps of the same run can read what an earlier one committed (an import that then estimates the
poses of its recording in place). Progress meant to survive a failure (a training run's
checkpoints, a sweep's finished cells: what a rerun resumes from) is written under
`outside_all_or_nothing`.
"""

from __future__ import annotations

import os
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import TYPE_CHECKING

from ndfa.core.errors import OutputError

if TYPE_CHECKING:  # polars only for the annotation: importing this module stays light
    import polars as pl


class Staged:
    """A temporary path to write in place of `path`: `commit()` moves it onto `path`, `discard()`
    drops it. For writers that stay open across calls (a recording, a Rerun stream); a block of
    code uses `atomic_path` or `atomic_dir`.

    make_parents: create `path`'s folder if missing; False lets a missing folder fail here (OSError).
    """

    def __init__(self, path: str | Path, make_parents: bool = True) -> None:
        self.path = Path(path)
        _refuse_special(self.path)
        if make_parents:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except (FileExistsError, NotADirectoryError):
                raise OutputError(f"{self.path}: a file is in the way of its folder") from None
            except OSError as error:
                raise OutputError(f"{self.path}: cannot make its folder ({error.strerror or error})") from None
        self.folder = self.path.parent / f".{self.path.name}.tmp-{secrets.token_hex(4)}"
        try:
            self.folder.mkdir()
        except OSError as error:
            if not make_parents:
                raise  # the caller asked for the OSError, to say it its own way (the recording writer)
            raise OutputError(f"{self.path}: cannot write in {self.path.parent} ({error.strerror or error})") from None
        self.temporary = self.folder / self.path.name
        self._outputs = _outputs.get()
        self._keeps_previous = False  # its hidden folder holds what `path` was, for `all_or_nothing`
        if self._outputs is not None:
            self._outputs.open.append(self)

    def commit(self) -> None:
        """Move the temporary onto `path` (a file replaces a file, a folder an empty folder); on
        failure `path` stays as it was and the temporary is removed. Inside `all_or_nothing`,
        what `path` was is kept until the block ends."""
        kept = False
        try:
            _refuse_special(self.path)
            if self.temporary.is_dir() != self.path.is_dir() and self.path.exists():
                expected = "folder" if self.temporary.is_dir() else "file"
                raise OutputError(f"{self.path}: is a {'file' if expected == 'folder' else 'directory'}, "
                                  f"expected a {expected}; left as it was")
            try:
                if self._outputs is not None:
                    kept = self._outputs.keep_previous(self)
                os.replace(self.temporary, self.path)
            except OSError as error:
                if kept:  # the previous one back where it was: nothing of this commit remains
                    self._outputs.restore(self.path, self.folder)
                    kept = False
                raise OutputError(f"{self.path}: cannot be replaced ({error.strerror or error})") from None
        finally:
            if self._outputs is not None and self in self._outputs.open:
                self._outputs.open.remove(self)
            self._keeps_previous = kept
            self.discard()

    def discard(self) -> None:
        """Remove the temporary (and its hidden folder, unless it keeps what `path` was for
        `all_or_nothing`); `path` stays as it was."""
        if self._keeps_previous:
            return
        if self._outputs is not None and self in self._outputs.open:
            self._outputs.open.remove(self)
        shutil.rmtree(self.folder, ignore_errors=True)


class _Outputs:
    """What one `all_or_nothing` block has written: the temporaries still open, each commit's path
    with the hidden folder that keeps what it replaced (None: nothing was there), the outputs the
    command declared with the nearest folder that existed then."""

    def __init__(self) -> None:
        self.open: list[Staged] = []
        self.committed: list[tuple[Path, Path | None]] = []
        self.declared: list[tuple[Path, Path]] = []

    def keep_previous(self, staged: Staged) -> bool:
        """Before `staged` is renamed onto its path: keep what is there (the first time this block
        replaces it) in the staged hidden folder. True when something was kept."""
        path = staged.path
        if any(done == path for done, _ in self.committed):
            return False  # an earlier commit of this block keeps the original already
        if not os.path.lexists(path):
            self.committed.append((path, None))
            return False
        previous = staged.folder / ".previous"
        if path.is_dir() and not path.is_symlink():
            os.rename(path, previous)  # an empty folder (anything else is refused before)
        else:
            try:
                os.link(path, previous, follow_symlinks=False)  # the rename onto `path` stays atomic
            except OSError:  # a filesystem without hard links
                shutil.copy2(path, previous, follow_symlinks=False)
        self.committed.append((path, staged.folder))
        return True

    def restore(self, path: Path, folder: Path | None) -> None:
        """Put back what `path` was before this block (nothing, when `folder` is None)."""
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        if folder is not None:
            if os.path.lexists(folder / ".previous"):
                os.rename(folder / ".previous", path)
            shutil.rmtree(folder, ignore_errors=True)
        self.committed = [(p, f) for p, f in self.committed if p != path]

    def undo(self) -> None:
        for staged in list(self.open):
            staged.discard()
        for path, folder in reversed(self.committed):
            try:
                self.restore(path, folder)
            except OSError:  # its folder removed meanwhile (a scratch folder): nothing there to restore
                pass
        for path, existing in reversed(self.declared):
            for folder in [path, *path.parents]:  # the folders made below the one that existed
                if folder == existing or existing not in folder.parents:
                    break
                try:
                    folder.rmdir()  # only when empty
                except FileNotFoundError:  # the output itself, removed above
                    continue
                except OSError:
                    break

    def finish(self) -> None:
        for staged in list(self.open):  # a writer that never committed: its temporary goes
            staged.discard()
        for _, folder in self.committed:
            if folder is not None:
                shutil.rmtree(folder, ignore_errors=True)


_outputs: ContextVar[_Outputs | None] = ContextVar("ndfa_outputs", default=None)


@contextmanager
def all_or_nothing() -> Iterator[None]:
    """Every output committed inside the block stays only if the block ends without an error (see
    the module's docstring); otherwise each is as it was before, and no temporary remains."""
    outputs = _Outputs()
    token = _outputs.set(outputs)
    try:
        yield
    except BaseException:  # an interruption too: a half-done run leaves no half-done outputs
        outputs.undo()
        raise
    else:
        outputs.finish()
    finally:
        _outputs.reset(token)


@contextmanager
def outside_all_or_nothing() -> Iterator[None]:
    """Commits inside the block are final even when the enclosing `all_or_nothing` fails: progress a
    later run resumes from."""
    token = _outputs.set(None)
    try:
        yield
    finally:
        _outputs.reset(token)


def declare_output(path: str | Path) -> None:
    """Inside `all_or_nothing`: `path` is an output, and the folders that will be made for it are
    removed again (when empty) if the block fails. Outside: nothing."""
    outputs = _outputs.get()
    if outputs is None:
        return
    path = Path(path).absolute()
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    outputs.declared.append((path, existing))


def _refuse_special(path: Path) -> None:
    """OutputError when `path` (followed through links) is a device, FIFO or socket."""
    try:
        mode = path.stat().st_mode
    except OSError:  # nothing there (or nothing reachable): the writes will say what is wrong
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise OutputError(f"{path}: is a special file (device, FIFO or socket); refusing to replace it")


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path (with `path`'s name) to write to: moved onto `path` when the block ends
    without an error, removed otherwise. `path`'s folder is made if missing."""
    staged = Staged(path)
    try:
        yield staged.temporary
        staged.commit()
    finally:
        staged.discard()


@contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """`atomic_path` for a folder: an empty temporary folder to fill, renamed to `path` (which must
    not exist or be an empty folder) when the block ends without an error."""
    with atomic_path(path) as temporary:
        temporary.mkdir()
        yield temporary


def write_parquet(frame: pl.DataFrame, path: str | Path) -> Path:
    """`frame` as parquet at `path`, atomically."""
    with atomic_path(path) as temporary:
        frame.write_parquet(temporary)
    return Path(path)
