"""The one property every fuzz test checks, on the real `ndfa` entry point run in-process.

For any input, a command either
- exits 0 with a sane result (the caller's `check_result`), or
- exits 2 with exactly one line on stderr, an "error:" line that names the input;
and it never
- raises anything else (a traceback) or exits with another code,
- runs longer than DEADLINE_S of CPU, or 12 times that of wall time (a SIGPROF or SIGALRM interrupts it),
- leaves a temporary file beside its output, or anything under the output's name after a failure,
- changes an output file that existed before a failed run.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import shutil
import signal
import sys
import tempfile
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

DEADLINE_S = 10.0  # CPU seconds per input
WALL_FACTOR = 12  # the wall-time limit, in DEADLINE_S: 120 s, what issue 31 called a hang

# Inputs checked in this session, by command ("info", "ingest tum", ...): the fuzz conftest reports them.
CHECKED: Counter[str] = Counter()


# Where an input that breaks the property is kept, to be replayed or added to corpus/regressions/.
FAILURES = Path(os.environ.get("NDFA_FUZZ_FAILURES", Path(tempfile.gettempdir()) / "ndfa-fuzz-failures"))


class Blob(bytes):
    """A generated file's bytes, shown by size and hash in Hypothesis' report (not kilobytes of escapes)."""

    def __repr__(self) -> str:
        return f"<{len(self)} bytes, sha1 {hashlib.sha1(self).hexdigest()[:12]}>"


@contextlib.contextmanager
def kept_on_failure(path: Path) -> Iterator[None]:
    """Copy the input at `path` (a file or a folder) to FAILURES when the block fails the property."""
    try:
        yield
    except AssertionError as error:
        FAILURES.mkdir(parents=True, exist_ok=True)
        digest = hashlib.sha1(str(error).encode()).hexdigest()[:12]
        kept = FAILURES / f"{digest}-{path.name}"
        if path.is_dir():
            shutil.copytree(path, kept, dirs_exist_ok=True, symlinks=True)
        elif path.exists():
            shutil.copyfile(path, kept)
        raise AssertionError(f"{error}\n(input kept as {kept})") from None


class Hang(Exception):
    """The command ran past the deadline."""


@dataclass
class Outcome:
    args: list[str]
    code: int
    stdout: str
    stderr: str
    seconds: float

    def describe(self) -> str:
        return (f"ndfa {' '.join(self.args)}\n-> exit {self.code} after {self.seconds:.1f} s\n"
                f"--- stdout ---\n{self.stdout[-3000:]}\n--- stderr ---\n{self.stderr[-6000:]}")


@contextlib.contextmanager
def _deadline(seconds: float) -> Iterator[None]:
    """Raise Hang once the command has used `seconds` of CPU, or WALL_FACTOR times that in wall time.
    CPU time is what a loop spends whatever the machine's load (on 2 cores shared by 30 processes a
    1-second import took over 10 s of wall time, which the wall clock alone called a hang); the wall
    limit still catches a command that waits on something forever."""
    def expire(signum, frame):  # noqa: ANN001
        clock = "of CPU" if signum == signal.SIGPROF else "of wall time"
        raise Hang(f"ran longer than {seconds if signum == signal.SIGPROF else seconds * WALL_FACTOR:g} s {clock}")

    previous = {sig: signal.signal(sig, expire) for sig in (signal.SIGPROF, signal.SIGALRM)}
    signal.setitimer(signal.ITIMER_PROF, seconds)
    signal.setitimer(signal.ITIMER_REAL, seconds * WALL_FACTOR)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_PROF, 0)
        signal.setitimer(signal.ITIMER_REAL, 0)
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run_cli(args: list[str], deadline_s: float = DEADLINE_S) -> Outcome:
    """Run `ndfa ARGS` through `ndfa.cli.main` (what the installed command runs), capturing its
    exit code, stdout and stderr. A traceback is captured as stderr with exit code 1, as Python
    would print it."""
    import traceback

    from ndfa.cli import main

    stdout, stderr = io.StringIO(), io.StringIO()
    saved_argv, saved_showwarning = sys.argv, warnings.showwarning
    sys.argv = ["ndfa", *args]
    start = time.perf_counter()
    code = 0
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("default")
            try:
                with _deadline(deadline_s):
                    main()
            except SystemExit as exit_:
                code = exit_.code if isinstance(exit_.code, int) else (0 if exit_.code is None else 1)
            except Hang:
                code = -1
                stderr.write(traceback.format_exc())
            except BaseException:  # noqa: BLE001 - what the user would see as a traceback
                code = 1
                stderr.write(traceback.format_exc())
    finally:
        sys.argv, warnings.showwarning = saved_argv, saved_showwarning
    for warning in caught:  # what Python would have printed: ndfa's own warnings are printed by main
        stderr.write(warnings.formatwarning(warning.message, warning.category, warning.filename, warning.lineno))
    return Outcome(list(args), code, stdout.getvalue(), stderr.getvalue(), time.perf_counter() - start)


def _listing(folder: Path) -> set[str]:
    return {p.name for p in folder.iterdir()} if folder.is_dir() else set()


def check_cli(args: list[str], names: list[str], output: Path | None = None,
              check_result: Callable[[Outcome], None] | None = None,
              deadline_s: float = DEADLINE_S, progress_on_stderr: bool = False) -> Outcome:
    """Run `ndfa ARGS` and assert the property. `names`: what the error line may name the input
    by (its path, or the path of a file inside it); `output`: the command's output file, if any
    (a file there before the run must survive a failure unchanged); `check_result` asserts that a
    successful run's result is sane. `progress_on_stderr`: the command reports its progress on
    stderr (`ndfa detect`: where each session's world came from), so lines before the error line are
    allowed, as long as none is a traceback or a warning from a library."""
    before_listing = _listing(output.parent) if output is not None else set()
    before = output.read_bytes() if output is not None and output.is_file() else None

    outcome = run_cli(args, deadline_s)
    CHECKED[" ".join(args[:2]) if args[0] == "ingest" else args[0]] += 1

    assert outcome.code in (0, 2), f"exit code {outcome.code} (a traceback or a hang):\n{outcome.describe()}"
    if output is not None:
        new = _listing(output.parent) - before_listing - {output.name}
        assert not new, f"left {sorted(new)} beside the output:\n{outcome.describe()}"
    if outcome.code == 2:
        lines = outcome.stderr.strip("\n").split("\n")
        if progress_on_stderr:
            assert not any("Traceback" in line or "Warning: " in line for line in lines), outcome.describe()
            assert sum(line.startswith("error: ") for line in lines) == 1, outcome.describe()
            lines = lines[-1:]
        assert len(lines) == 1 and lines[0].startswith("error: "), \
            f"exit 2 without exactly one error line:\n{outcome.describe()}"
        assert any(name in lines[0] for name in names), f"the error does not name the input:\n{outcome.describe()}"
        if output is not None:
            if before is None:
                assert not output.exists(), f"a failed run left {output}:\n{outcome.describe()}"
            else:
                assert output.is_file() and output.read_bytes() == before, \
                    f"a failed run changed the existing {output}:\n{outcome.describe()}"
    else:
        library = [line for line in outcome.stderr.splitlines() if "Warning: " in line]
        assert not library, f"a library's warning reached the user:\n{outcome.describe()}"
        if check_result is not None:
            check_result(outcome)
    return outcome
