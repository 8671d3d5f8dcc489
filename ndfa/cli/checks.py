"""Options and output paths checked where they enter: as typer callbacks, before a command does any work.

A bad value must fail in one line naming the option and the value (an `OptionError`, exit 2),
not after minutes of rendering or detection, and not deep inside as a traceback. So each numeric
option declares its range once, beside its help text (`callback=positive`, `callback=at_least(1)`),
and each output path declares what it must be (`callback=output_file`, `callback=output_dir`).

Numbers: NaN and infinity are refused everywhere (no option of ndfa means anything with them);
the bounds say what else is meaningless (a zero interval length, a negative count).

Output paths, checked for what can be known before the run (the atomic writer, `ndfa.io.atomic`,
checks again when it renames):
- a file option may not name a directory, and no output may name a special file (a device node,
  FIFO or socket): the rename would replace it;
- the folder that would hold it must be writable; folders that do not exist yet are made by the
  writer (`--log out/run.rrd` in a fresh checkout), so the nearest existing one is what is tested,
  and it must be a folder;
- it may not be, or lead to (a link, `..`, a hard link), one of the command's inputs or another of
  its outputs: the run would destroy what it reads (`refuse_outputs_among_inputs`, once every
  option is parsed). Each output is also declared to the command's `all_or_nothing` block
  (`ndfa.io.atomic`), which removes the folders made for it when the command fails.
"""

from __future__ import annotations

import math
import operator
import os
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import typer

from ndfa.core.errors import OptionError
from ndfa.io.atomic import declare_output

Callback = Callable[[typer.CallbackParam, Any], Any]


def option_name(param: typer.CallbackParam) -> str:
    """How the user wrote the option: its longest flag (`--tree-length`), or the argument's name."""
    flags = [flag for flag in param.opts if flag.startswith("-")]
    return max(flags, key=len) if flags else (param.name or "value").upper()


def in_range(*, gt: float | None = None, ge: float | None = None, lt: float | None = None,
             le: float | None = None, why: str = "") -> Callback:
    """A callback that lets a value (each value of a list; None: not given) through when it is a
    finite number within the bounds, and otherwise fails naming the option and the value (and,
    given `why`, why the bound is where it is). Integers of any size are compared exactly: never
    converted to a float, which overflows beyond 1e308."""
    bounds = [(">", gt), (">=", ge), ("<", lt), ("<=", le)]
    tests = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}
    wanted = " and ".join(f"{sign} {number_text(bound)}" for sign, bound in bounds if bound is not None)
    because = f" ({why})" if why else ""

    def check(param: typer.CallbackParam, value: Any) -> Any:
        for number in value if isinstance(value, (list, tuple)) else [value]:
            if number is None:
                continue
            finite = isinstance(number, int) or math.isfinite(number)
            ok = finite and all(tests[sign](number, bound) for sign, bound in bounds if bound is not None)
            if not ok:
                must = (wanted or "finite") if isinstance(number, int) else "a finite number" + (f" {wanted}" if wanted else "")
                got = number_text(number) if isinstance(number, int) else repr(number)
                raise OptionError(f"{option_name(param)} must be {must}{because}, got {got}")
        return value

    return check


def number_text(value: float) -> str:
    """A bound or a value as the user would write it; an integer too long to read, by its digits."""
    text = str(value) if isinstance(value, int) else f"{value:g}"
    return text if len(text) <= 24 else f"{text[:6]}...({len(text)} digits)"


def non_empty(param: typer.CallbackParam, value: str | None) -> str | None:
    """A callback for a name (a session's): not empty, not only blanks (None: not given)."""
    if value is not None and not value.strip():
        raise OptionError(f"{option_name(param)} must be a non-empty name, got {value!r}")
    return value


def category_list(param: typer.CallbackParam, value: str | None) -> str | None:
    """A callback for object categories, comma-separated ("mug,bowl,cup"): distinct, each one of
    `ndfa.sim.categories.CATEGORIES` ("all": every one); returned in that canonical spelling
    (None, an option left unset, passes)."""
    from ndfa.sim.categories import CATEGORIES  # lazy: the simulator's meshes import trimesh

    if value is None:
        return None
    names = list(CATEGORIES) if value.strip() == "all" else [name.strip() for name in value.split(",")]
    unknown = [name for name in names if name not in CATEGORIES]
    if unknown or not names or len(set(names)) != len(names):
        raise OptionError(f"{option_name(param)} must be distinct names among {', '.join(CATEGORIES)} (or all), "
                          f"got {value!r}")
    return ",".join(names)


def at_least(low: float) -> Callback:
    """`in_range(ge=low)`: counts, strides, seeds."""
    return in_range(ge=low)


positive = in_range(gt=0)          # lengths, scales, rates
non_negative = in_range(ge=0)      # weights, noise levels, counts that may be zero
fraction = in_range(ge=0, le=1)    # shares
at_least_one = at_least(1)      # frame steps, strides, threads, workers
# Seeds: recordings and tables store them as 64-bit integers.
seed_range = in_range(ge=0, le=2**63 - 1, why="a seed is stored as a 64-bit integer")
# CPU threads and parallel workers: more than any machine has cores is a typo.
thread_count = in_range(ge=1, le=1024, why="more than any machine has cores")


# The outputs of the command being parsed: parameter name -> (option as written, path).
_outputs: ContextVar[dict[str, tuple[str, Path]] | None] = ContextVar("ndfa_cli_outputs", default=None)


@contextmanager
def command_outputs() -> Iterator[None]:
    """Collect the output options of the command parsed inside the block (`refuse_outputs_among_inputs`)."""
    token = _outputs.set({})
    try:
        yield
    finally:
        _outputs.reset(token)


def _output(param: typer.CallbackParam, value: Path | None, kind: str | None) -> Path | None:
    if value is not None:
        check_output_path(value, option_name(param), kind=kind)
        outputs = _outputs.get()
        if outputs is not None and param.name:
            outputs[param.name] = (option_name(param), value)
        declare_output(value)
    return value


def output_file(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for an option naming a file to write: not a directory, not a special file, and
    in a folder that is, or can be made, writable."""
    return _output(param, value, "file")


def output_dir(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for an option naming a folder to write into (made if missing)."""
    return _output(param, value, "folder")


def output_path(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for an output that is a file or a folder depending on other options (`export bag`)."""
    return _output(param, value, None)


def refuse_outputs_among_inputs(params: dict[str, Any]) -> None:
    """OptionError when an output option of the command (collected by `command_outputs`) is, or
    resolves to, one of its input paths (every other path-valued parameter) or another output."""
    outputs = _outputs.get() or {}
    inputs = [path for name, value in params.items() if name not in outputs
              for path in (value if isinstance(value, (list, tuple)) else [value]) if isinstance(path, Path)]
    seen: list[tuple[str, Path]] = []
    for option, path in outputs.values():
        for other in inputs:
            if _same_path(path, other):
                raise OptionError(f"{option} {path}: is the input {other}; refusing to overwrite what the run reads")
        for earlier, other in seen:
            if _same_path(path, other):
                raise OptionError(f"{option} {path}: is also {earlier} {other}; give each output its own path")
        seen.append((option, path))


def _same_path(a: Path, b: Path) -> bool:
    """The same file or folder: one inode when both exist (links, `..`, hard links), else the same
    path once links and `..` are resolved."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.absolute().resolve() == b.absolute().resolve()


def check_output_path(path: Path, option: str, kind: str | None) -> None:
    """Raise OptionError when `path` cannot be written as a `kind` ("file", "folder", None: either)."""
    where = f"{option} {path}"
    try:
        mode = path.stat().st_mode  # follows links: a link to /dev/null is a device too
    except (FileNotFoundError, NotADirectoryError):  # nothing there yet (a file in the way: below)
        mode = None
    except OSError as error:
        raise OptionError(f"{where}: cannot be used as an output ({error.strerror or error})") from None
    if mode is not None:
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            raise OptionError(f"{where}: is a special file (device, FIFO or socket), not a {kind or 'file'}; "
                              "refusing to replace it")
        if kind == "file" and stat.S_ISDIR(mode):
            raise OptionError(f"{where}: is a directory, expected a file")
        if kind == "folder" and not stat.S_ISDIR(mode):
            raise OptionError(f"{where}: is a file, expected a directory")
    folder = path if mode is not None and stat.S_ISDIR(mode) else path.absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OptionError(f"{where}: {folder} is not a directory, so nothing can be written under it")
    try:  # os.access says yes to root even on a read-only filesystem: write a probe instead
        with tempfile.TemporaryFile(dir=folder, prefix=".ndfa-write-test-"):
            pass
    except OSError as error:
        raise OptionError(f"{where}: cannot write in {folder} ({error.strerror or error})") from None


def input_file(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for an option naming a file to read (a checkpoint, a recording): it exists and
    is a regular file."""
    for path in value if isinstance(value, (list, tuple)) else [value]:
        if path is not None and not path.is_file():
            problem = "is a directory" if path.is_dir() else "is not a regular file" if path.exists() else "no such file"
            raise OptionError(f"{option_name(param)} {path}: {problem}")
    return value


def input_dir(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for an option naming a folder to read."""
    if value is not None and not value.is_dir():
        problem = ("not a directory" if value.exists() else
                   "a symbolic link that leads nowhere (broken, or a loop)" if value.is_symlink() else "no such directory")
        raise OptionError(f"{option_name(param)} {value}: {problem}")
    return value


def shipped_weights(path: Path) -> Path:
    """`path` itself, or where a bare name that is no file names shipped weights: `mugs` (the
    default, NDF v2) or `objects` (NDF v3, every category), ndfa/ndf/weights/ndf_NAME.pt."""
    if path.exists() or len(path.parts) != 1:
        return path
    from ndfa.ndf.encoder import WEIGHTS_DIR

    shipped = WEIGHTS_DIR / f"ndf_{path}.pt"
    return shipped if shipped.is_file() else path


def checkpoint(param: typer.CallbackParam, value: Path | None) -> Path | None:
    """A callback for `--weights`: a checkpoint file or the name of shipped weights
    (`shipped_weights`). The file is loaded once here (a fraction of a second), so that a file
    that is no ndfa checkpoint fails before the recordings are read, not after."""
    if isinstance(value, (list, tuple)):
        value = type(value)(None if path is None else shipped_weights(path) for path in value)
    elif value is not None:
        value = shipped_weights(value)
    input_file(param, value)
    for path in value if isinstance(value, (list, tuple)) else [value]:
        if path is not None:
            from ndfa.ndf.checkpoint import load_model

            load_model(path)
    return value
