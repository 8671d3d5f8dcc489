"""Writing a file or folder so that no reader ever sees half of it: write beside it, then rename over it.

Everything ndfa writes goes through `Staged`: the temporary lies in a hidden folder next to the
destination (`.NAME.tmp-XXXXXXXX/NAME`), so that
- the final rename stays on one filesystem (os.replace is atomic only there);
- the temporary keeps the destination's own name: writers that derive something from it (numpy
  appending ".npz", PIL choosing the format by suffix, a ROS2 bag naming its database after its
  folder) write what they would write at the destination;
- a crash leaves at most one hidden folder, never half a file at the destination nor a clobbered
  previous one.
"""

from __future__ import annotations

import os
import secrets
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

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
        if make_parents:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self.folder = self.path.parent / f".{self.path.name}.tmp-{secrets.token_hex(4)}"
        self.folder.mkdir()
        self.temporary = self.folder / self.path.name

    def commit(self) -> None:
        """Move the temporary onto `path` (a file replaces a file, a folder an empty folder)."""
        os.replace(self.temporary, self.path)
        self.discard()

    def discard(self) -> None:
        """Remove the temporary (and its hidden folder); `path` stays as it was."""
        shutil.rmtree(self.folder, ignore_errors=True)


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
