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
"""

from __future__ import annotations

import os
import secrets
import shutil
import stat
from collections.abc import Iterator
from contextlib import contextmanager
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

    def commit(self) -> None:
        """Move the temporary onto `path` (a file replaces a file, a folder an empty folder); on
        failure `path` stays as it was and the temporary is removed."""
        try:
            _refuse_special(self.path)
            if self.temporary.is_dir() != self.path.is_dir() and self.path.exists():
                expected = "folder" if self.temporary.is_dir() else "file"
                raise OutputError(f"{self.path}: is a {'file' if expected == 'folder' else 'directory'}, "
                                  f"expected a {expected}; left as it was")
            try:
                os.replace(self.temporary, self.path)
            except OSError as error:
                raise OutputError(f"{self.path}: cannot be replaced ({error.strerror or error})") from None
        finally:
            self.discard()

    def discard(self) -> None:
        """Remove the temporary (and its hidden folder); `path` stays as it was."""
        shutil.rmtree(self.folder, ignore_errors=True)


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
