"""Writing a file so that no reader ever sees half of it: write beside it, then rename over it."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import polars as pl


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path next to `path` (its folder made if missing) to write to: renamed over
    `path` when the block ends without an error, removed otherwise, so a crash or a bad input
    never leaves half a file and never clobbers the previous one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        yield temporary
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def write_parquet(frame: pl.DataFrame, path: str | Path) -> Path:
    """`frame` as parquet at `path`, atomically."""
    with atomic_path(path) as temporary:
        frame.write_parquet(temporary)
    return Path(path)
